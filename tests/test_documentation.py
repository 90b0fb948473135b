"""The documentation is executed (issue 28).

Every command line the documentation shows - README.md, every ``docs/**/*.md`` (fenced blocks and
inline code) and every example in the ``--help`` of every subcommand (read by running
``phireman ... --help``) - is collected, and each one is run as a user runs it: the line, through
bash, in a fresh directory, with this venv first on PATH and ``HOME`` in that directory. Only the
shrinking rewrites of the table below are applied (fewer seeds, shorter missions, port 0 for fixed
ports, ``/tmp/`` inside the directory); a rewrite may change a value or add a flag, never remove a
documented flag (checked). Each run asserts its exit status and what the command promises: the
files it writes, the page it serves (HTTP 200 and its API), the export it writes (parsed), and the
effect of each documented flag that can be seen from outside.

What is ours: ``phireman ...`` and ``python ...`` lines. ``python bench/...`` lines are recipes in
the measurement records (``docs/results/``, ``docs/tuning/``): benchmarks are run by hand, never by
tests (CONTRIBUTING.md), and several check out old commits; each documented script must exist and
accept every documented flag (its ``--help`` is run). Mentions of a subcommand in prose (``phireman
sweep``) are checked the same way against ``phireman ... --help``. Lines that cannot run here are in
``SKIP`` with the reason; known defects other engineers are fixing are ``xfail(strict=True)``.
A documented command in no table, or a table entry no longer documented, fails
``test_every_documented_command_is_classified``: new documentation is caught.

Nothing here imports ``mission``: only the command line is used, so the test survives any layout of
the package.
"""

from __future__ import annotations

import json
import re
import shutil
import socket
import tempfile
import threading
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from user_cli import PHIREMAN, VENV_BIN, Served, http_get, run

ROOT = Path(__file__).resolve().parents[1]
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]

# ----------------------------------------------------------------------------------------------
# Collection
# ----------------------------------------------------------------------------------------------

# A program of ours and at least one argument (a bare `phireman` in prose is the method's name).
_OURS = re.compile(r"^(?:\S*/)?(?:phireman|python(?:3(?:\.\d+)?)?)\s+\S")
_PREFIX = re.compile(r"^(?:\$\s+|nice -n \d+\s+|[A-Z_]+=\S*\s+)+")


def _strip_comment(line: str) -> str:
    return re.sub(r"\s+#\s.*$|\s+#$", "", line)


def _norm(line: str) -> str:
    return " ".join(_strip_comment(line).split())


def _logical_lines(lines: list[str]) -> list[str]:
    """Lines with their ``\\`` continuations joined."""
    out: list[str] = []
    buf = ""
    for raw in lines:
        line = raw.rstrip()
        if line.endswith("\\"):
            buf += line[:-1] + " "
            continue
        out.append(buf + line)
        buf = ""
    if buf:
        out.append(buf)
    return out


def _is_ours(line: str) -> bool:
    return bool(_OURS.match(_PREFIX.sub("", line.strip())))


def _from_markdown(text: str) -> list[str]:
    found: list[str] = []
    fence: list[str] | None = None
    indented: list[str] = []
    for line in text.splitlines():
        if line.strip().startswith("```"):
            if fence is None:
                fence = []
                continue
            # A block with '$ ' prompts shows commands and their output: only prompts are commands.
            prompts: list[str] = []
            for s in fence:
                if s.strip().startswith("$ "):
                    prompts.append(s.strip()[2:])
                elif prompts and prompts[-1].rstrip().endswith("\\"):
                    prompts.append(s.strip())  # a prompt's continuation line

            for cmd in _logical_lines(prompts or [s.strip() for s in fence]):
                if _is_ours(cmd):
                    found.append(_norm(cmd))
            fence = None
            continue
        if fence is not None:
            fence.append(line)
            continue
        if line.startswith("    ") and _is_ours(line):  # an indented code block's command
            indented.append(line)
            continue
        if indented and not line.rstrip().endswith("\\"):
            found.extend(_norm(c) for c in _logical_lines(indented) if _is_ours(c))
            indented = []
        for span in re.findall(r"`([^`\n]+)`", line):
            if _is_ours(span):
                found.append(_norm(span))
    found.extend(_norm(c) for c in _logical_lines(indented) if _is_ours(c))
    return found


def _help(*words: str) -> str:
    res = run([PHIREMAN, *words, "--help"], cwd=ROOT, timeout=120)
    assert res.returncode == 0, res.stderr
    return res.stdout


def _subcommands(help_text: str, header: str) -> list[str]:
    """The names listed under ``header`` (argparse's sub-command list) in ``help_text``."""
    names: list[str] = []
    block = help_text.split(header, 1)[1].split("\n\n", 1)[0]
    for line in block.splitlines():
        m = re.match(r"^    (\w[\w-]*)(?:\s|$)", line)
        if m:
            names.append(m.group(1))
    return names


def _from_help(text: str) -> list[str]:
    """The example lines of a --help: indented by 2 to 6 spaces (wrapped option help is indented
    further, prose not at all), with their continuation lines."""
    lines = [s.strip() for s in text.splitlines()]
    starts = {i for i, s in enumerate(text.splitlines()) if re.match(r"^ {2,6}phireman ", s)}
    out: list[str] = []
    i = 0
    while i < len(lines):
        if i in starts:
            cmd = lines[i]
            while cmd.endswith("\\") and i + 1 < len(lines):
                i += 1
                cmd = cmd[:-1] + " " + lines[i]
            out.append(_norm(cmd))
        i += 1
    return out


def collect() -> dict[str, list[str]]:
    """Every documented command line -> the places that show it (file, or 'phireman X --help')."""
    where: dict[str, list[str]] = {}
    for path in DOC_FILES:
        for cmd in _from_markdown(path.read_text()):
            where.setdefault(cmd, []).append(str(path.relative_to(ROOT)))
    pages: list[tuple[str, ...]] = [()]
    top = _help()
    for name in _subcommands(top, "COMMAND\n"):
        pages.append((name,))
        if name == "mission":
            pages += [("mission", s) for s in _subcommands(_help("mission"), "SUBCOMMAND\n")]
    with ThreadPoolExecutor(4) as pool:
        texts = list(pool.map(lambda w: _help(*w), pages))
    for words, text in zip(pages, texts):
        for cmd in _from_help(text):
            where.setdefault(cmd, []).append(" ".join(("phireman", *words, "--help")))
    return where


# ----------------------------------------------------------------------------------------------
# The table: how each documented command is run and what it must produce
# ----------------------------------------------------------------------------------------------


@dataclass
class Ctx:
    """One run: its directory, exit status and output; ``served`` for interactive cases."""

    cwd: Path
    cmd: str
    rc: int | None = None
    out: str = ""
    err: str = ""
    served: Served | None = None
    extra: dict = field(default_factory=dict)

    def fail(self, msg: str) -> AssertionError:
        return AssertionError(
            f"{msg}\n$ {self.cmd}\n(exit {self.rc})\n--- stdout\n{self.out[-2500:]}"
            f"\n--- stderr\n{self.err[-2500:]}"
        )

    def expect(self, cond: object, msg: str) -> None:
        if not cond:
            raise self.fail(msg)

    def text(self) -> str:
        return self.out + self.err

    def has(self, *patterns: str) -> None:
        for p in patterns:
            self.expect(re.search(p, self.text()), f"output lacks /{p}/")

    def file(self, rel: str) -> Path:
        p = self.cwd / rel
        self.expect(p.is_file() and p.stat().st_size > 0, f"{rel} not written")
        return p

    def run_dirs(self, parent: str) -> list[Path]:
        d = self.cwd / parent
        dirs = sorted(p for p in d.iterdir() if p.is_dir()) if d.is_dir() else []
        self.expect(dirs, f"no run directory under {parent}")
        return dirs


Check = Callable[[Ctx], None]


@dataclass
class Case:
    """How one documented command is run.

    kind: 'run' (to its end), 'serve' (long-running: checked while it runs, then Ctrl-C),
    'help' (a mention of a subcommand: its --help lists every documented flag), 'bench' (a
    measurement recipe: the script's --help lists every documented flag).
    rewrite: (regex, replacement) pairs, each must match. pre: shell lines run first in the
    directory (a documented command the case depends on). fixture: (name, path): a shared run copied
    to ``path`` in the directory ('fly' or 'sim' run directory)."""

    kind: str = "run"
    rewrite: tuple[tuple[str, str], ...] = ()
    check: Check | None = None
    pre: tuple[str, ...] = ()
    fixture: tuple[tuple[str, str], ...] = ()
    xfail: str | None = None
    timeout: float = 240
    help_args: tuple[str, ...] = ()


def SKIP(reason: str) -> Case:
    return Case(kind="skip", xfail=reason)


# -- shrinking rewrites, each used below (reviewed: values and added flags only) -----------------
TINY_SIM = (r"$", " --seeds 2 --set n_steps=20 --no-progress")  # 2 seeds, 20 of 200 steps
SHORT_FLY = (r"$", " --duration-s 20 --speedup 60")  # 20 s of mission at 60x
SHORT_FLY_NOWAIT = (r"$", " --duration-s 20 --speedup 60 --no-wait")
FEW_FRAMES = (r"(phireman replay \S+)", r"\1 --max-frames 5")  # GIF of 5 frames, not 100
SEEDS_TO_1 = (r"--seeds \d+", "--seeds 1")
SEEDS_TO_2 = (r"--seeds \d+", "--seeds 2")  # tune refuses fewer than 2
STEPS_20 = (r"$", " --set n_steps=20")
PORT_0 = (r"--serve (\d+\.\d+\.\d+\.\d+:)?8080", r"--serve \g<1>0")  # an ephemeral port


# -- checks ------------------------------------------------------------------------------------
def sim_header(*want: str) -> Check:
    def check(c: Ctx) -> None:
        c.has(r"TU1 = \d", r"TU2 = \d", *want)

    return check


def sim_mission_then_replay(run_dir: str, out: str | None = None, frames: int = 5) -> Check:
    def check(c: Ctx) -> None:
        for f in ("truth.npz", "metrics.csv", "summary.json", "mission.yaml"):
            c.file(f"{run_dir}/{f}")
        pictures(c, out or run_dir, frames)

    return check


def pictures(c: Ctx, where: str, frames: int | None = 5) -> None:
    from PIL import Image

    c.file(f"{where}/fig2_timeseries.png")
    c.file(f"{where}/frames.png")
    if frames is None:
        c.expect(not (c.cwd / where / "animation.gif").exists(), "--animation none drew a GIF")
        return
    with Image.open(c.file(f"{where}/animation.gif")) as gif:
        c.expect(gif.n_frames == frames, f"animation has {gif.n_frames} frames, not {frames}")


def newest_replayed(parent: str, frames: int = 5) -> Check:
    def check(c: Ctx) -> None:
        newest = c.run_dirs(parent)[-1]
        pictures(c, str(newest.relative_to(c.cwd)), frames)

    return check


def fly_run(parent: str = "runs", personality: str | None = None, seed: int | None = None) -> Check:
    def check(c: Ctx) -> None:
        c.has(r"TU1/TU2 as the station saw them: +\d", r"TU1/TU2 from the emulator's truth: +\d")
        d = c.run_dirs(parent)[-1]
        rel = str(d.relative_to(c.cwd))
        for f in ("flight.tlog", "events.jsonl", "metrics.csv", "truth.npz", "run.json"):
            c.file(f"{rel}/{f}")
        c.has(re.escape(f"run directory: {rel}"))
        info = json.loads((d / "run.json").read_text())
        if personality:
            c.expect(info["options"]["personality"] == personality, "--personality not applied")
            c.expect(f"{personality} drones" in c.text(), f"not flown on {personality}")
        if seed is not None:
            c.expect(info["seed"] == seed and d.name.endswith(f"-s{seed}"), "--seed not applied")

    return check


def sweep_store(store: str, runs: int, dry: bool = False) -> Check:
    def check(c: Ctx) -> None:
        if dry:
            c.has(rf"{runs} runs, 0 present, {runs} to run: about \d+ min")
            c.expect(not (c.cwd / store).exists(), "--dry-run wrote the store")
            return
        c.file(store)
        c.has(rf"= {runs} runs -> {re.escape(store)}", rf"{runs} completed now \(0 errors\)")
        if "--no-progress" in c.cmd:
            c.expect("it/s" not in c.err and "run/s" not in c.err, "--no-progress drew a bar")

    return check


def report_written(out: str, notes: str | None = None) -> Check:
    def check(c: Ctx) -> None:
        md = c.file(f"{out.rstrip('/')}/report.md").read_text()
        c.expect("Table II" in md, "report.md has no Table II")
        if notes:
            c.expect(notes in md, "--notes not appended")

    return check


def tune_record(settings: int, md: str | None = None) -> Check:
    """``settings`` grid points, each ranked in the output (the --grid values took effect)."""

    def check(c: Ctx) -> None:
        grid = [g.split("=", 1) for g in re.findall(r"--grid (\S+)", c.cmd)]
        points = 1
        for key, values in grid:
            points *= len(values.split(","))
            for v in values.split(","):
                c.has(rf"(?i){re.escape(key)}={re.escape(v)}\b")  # true is printed True
        c.expect(points == settings, f"{points} grid points, the table says {settings}")
        if md:
            p = c.cwd / md
            text = p.read_text() if p.is_file() else "".join(f.read_text() for f in p.glob("*.md"))
            c.expect(text, f"no Markdown record at {md}")

    return check


def mission_yaml(path: str | None, unit_m: float | None = None) -> Check:
    import yaml

    def check(c: Ctx) -> None:
        text = c.file(path).read_text() if path else c.out
        doc = yaml.safe_load(text)
        c.expect(isinstance(doc, dict) and doc.get("name"), "not a mission")
        if unit_m is not None:
            c.expect(f"1 paper length unit   = {unit_m:g} m" in text, "--unit-m not applied")
        if path:
            res = run([PHIREMAN, "check", path], c.cwd, timeout=60)
            c.expect(res.returncode == 0 and res.stdout.startswith("OK:"), res.stdout + res.stderr)

    return check


def export_geojson(path: str, at: tuple[float, ...]) -> Check:
    def check(c: Ctx) -> None:
        doc = json.loads(c.file(path).read_text())
        c.expect(doc["type"] == "FeatureCollection" and doc["features"], "empty GeoJSON")
        got = sorted({f["properties"]["t_mission_s"] for f in doc["features"] if "t_mission_s" in f["properties"]})  # fmt: skip
        c.expect(len(got) == len(at) and all(abs(g - a) < 2 for g, a in zip(got, at)),
                 f"--at snapshots {got}, asked {at}")  # fmt: skip

    return check


def export_kml(path: str) -> Check:
    def check(c: Ctx) -> None:
        root = ET.parse(c.file(path)).getroot()
        c.expect(root.tag.endswith("kml"), "not KML")
        c.expect(any((e.text or "").startswith("t+") for e in root.iter()), "no snapshot folder")

    return check


# -- interactive checks (the command is running; Ctrl-C after) ---------------------------------
def page(actions: bool = True, tiles: str | None = None, public: bool = False) -> Check:
    def check(c: Ctx) -> None:
        s = c.served
        assert s is not None
        pat = r"live view: (http://\S+)" if actions else r"live view \(read-only\): (http://\S+)"
        url = s.wait_for(pat).group(1)
        c.extra["url"] = url
        status, body = http_get(url)
        c.expect(status == 200 and b"<html" in body.lower(), f"GET {url}: {status}")
        meta = s.get_json(url + "api/meta")
        c.expect(meta["actions"] is actions, f"meta actions {meta['actions']}, want {actions}")
        frame = s.get_json(url + "api/frame")
        c.expect("v" in frame and "crews" in frame, "no frame")
        if actions:
            s.wait_for(r"operator key \(actions\): \S+")
        else:
            st, _ = _post(url + "api/action", {"action": "hold", "vehicle": "all"})
            c.expect(st == 403, f"read-only page accepted an action ({st})")
        if public:
            s.wait_for(r"reachable from other machines")
        if tiles is not None:
            c.expect(tiles in json.dumps(meta), f"--tiles {tiles} not in /api/meta")
            if not tiles.startswith("http"):
                st, _ = http_get(url + "tiles/15/5000/12000.png")
                c.expect(st == 200, f"tile from --tiles folder: HTTP {st}")

    return check


def rotation_page(swap_confirm: str) -> Check:
    """A flight with batteries served: the frame has the Relay rotation (docs/live_view.md) in the
    ``--swap-confirm`` mode asked for, and ``confirm_swap`` for "all" is refused (one vehicle at a
    time), with the operator key."""

    def check(c: Ctx) -> None:
        page()(c)
        s = c.served
        assert s is not None
        url = c.extra["url"]
        rot = s.get_json(url + "api/frame").get("rotation")
        c.expect(rot is not None, "no rotation in the frame of a mission with batteries")
        c.expect(rot["swap_confirm"] == swap_confirm, f"swap_confirm {rot['swap_confirm']}")
        c.expect(len(rot["pads"]) == 4, f"wildfire_2h has 4 pads, the frame {len(rot['pads'])}")
        key = s.wait_for(r"operator key \(actions\): (\S+)").group(1)
        body = {"action": "confirm_swap", "vehicle": "all"}
        st, text = _post(url + "api/action", body, {"X-Operator-Key": key})
        c.expect(st == 400 and b"name the vehicle" in text, f"confirm_swap all: {st} {text!r}")

    return check


def _post(url: str, body: dict, headers: dict | None = None) -> tuple[int, bytes]:
    import urllib.error
    import urllib.request

    req = urllib.request.Request(
        url, data=json.dumps(body).encode(), method="POST", headers=headers or {}
    )
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def replay_page(c: Ctx) -> None:
    s = c.served
    assert s is not None
    url = s.wait_for(r"replay of \S+ at (http://\S+)").group(1)
    status, _ = http_get(url)
    c.expect(status == 200, f"GET {url}: {status}")
    meta = s.get_json(url + "api/meta")
    frame = s.get_json(url + "api/frame?i=0")
    c.expect(meta.get("crews") and frame["v"]["id"], "empty replay")
    c.expect(s.proc.poll() is None, "the replay page stopped on its own")


def terrain_page(c: Ctx) -> None:
    """The replay of an in-process canyon run: the relief, link statuses, a link's profile."""
    replay_page(c)
    s = c.served
    assert s is not None
    url = s.wait_for(r"replay of \S+ at (http://\S+)").group(1)
    meta = s.get_json(url + "api/meta")
    c.expect(meta.get("terrain") and meta["terrain"]["url"] == "/api/terrain.png", "no terrain")
    status, png = http_get(url + "api/terrain.png")
    c.expect(status == 200 and png[:4] == b"\x89PNG", f"terrain.png: HTTP {status}")
    frame = s.get_json(url + "api/frame?i=150")
    links = frame["links"]
    c.expect(len(links["vv_status"]) == len(links["vv"]) // 2 > 0, "links without a status")
    prof = s.get_json(url + "api/profile?a=0,0,2103&b=0,330,2021.5")
    c.expect(prof["status_name"] == "blocked by terrain", f"base to canyon floor: {prof}")


# MAVLink forwarding: the test plays QGroundControl on a port of its own (port 0) and checks that
# vehicles' frames arrive; a command it sends (COMMAND_LONG from sysid 254, param1 = 28.0) appears
# in flight.tlog only when the output is not --forward-readonly (docs/live_view.md).
_MARK = 28.0


def _command_frame() -> bytes:
    from pymavlink.dialects.v20 import common as mavlink

    mav = mavlink.MAVLink(None, srcSystem=254, srcComponent=190)
    msg = mav.command_long_encode(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, _MARK, 0, 0, 0, 0, 0, 0)
    return msg.pack(mav)


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _tlog_has_mark(tlog: Path) -> bool:
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(str(tlog), dialect="common")
    while (msg := m.recv_match(type="COMMAND_LONG", blocking=False)) is not None:
        if msg.get_srcSystem() == 254 and msg.param1 == _MARK:
            return True
    return False


def forwarding(outputs: tuple[str, ...], readonly: bool, serve: bool = False) -> Check:
    """``outputs``: the kinds of the --forward URLs in order ('udpout', 'udpin', 'tcpin'); their
    ports are in c.extra['ports'] (set by the rewrite)."""

    def check(c: Ctx) -> None:
        s = c.served
        assert s is not None
        s.wait_for(r"forwarding MAVLink( to |: listening on )")
        if serve:
            page()(c)
        for kind, port in zip(outputs, c.extra["ports"]):
            data = _receive(kind, port, send=_command_frame())
            c.expect(data[:1] in (b"\xfd", b"\xfe"), f"{kind}:{port}: no MAVLink forwarded")
        c.extra["after"] = lambda: _forward_after(c, readonly)

    return check


def _receive(kind: str, port: int, send: bytes, deadline_s: float = 60.0) -> bytes:
    end = time.monotonic() + deadline_s
    if kind == "udpout":  # the station sends to us; we answer to where it sends from
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.bind(("127.0.0.1", port))
            sock.settimeout(1.0)
            while time.monotonic() < end:
                try:
                    data, peer = sock.recvfrom(65536)
                except TimeoutError:
                    continue
                sock.sendto(send, peer)
                time.sleep(0.3)
                sock.sendto(send, peer)
                return data
        return b""
    if kind == "udpin":  # the station listens; a peer is whoever sends first
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.settimeout(1.0)
            while time.monotonic() < end:
                sock.sendto(send, ("127.0.0.1", port))
                try:
                    data, _ = sock.recvfrom(65536)
                    sock.sendto(send, ("127.0.0.1", port))
                    return data
                except TimeoutError:
                    continue
        return b""
    while time.monotonic() < end:  # tcpin
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=2.0) as sock:
                sock.settimeout(5.0)
                data = sock.recv(65536)
                sock.sendall(send)
                time.sleep(0.5)
                return data
        except OSError:
            time.sleep(0.3)
    return b""


def _forward_after(c: Ctx, readonly: bool) -> None:
    tlog = c.run_dirs("runs")[-1] / "flight.tlog"
    c.expect(tlog.is_file(), "no flight.tlog")
    seen = _tlog_has_mark(tlog)
    if readonly:
        c.expect(not seen, "--forward-readonly: a forwarded command reached the vehicles")
    else:
        c.expect(seen, "a command sent through --forward did not reach the vehicles")


def forward_refusal(c: Ctx) -> None:
    """``--forward-overrides refuse``: a client's SET_MODE to a vehicle the station flies is
    answered by the vehicle's sysid with the station's STATUSTEXT, and recorded in events.jsonl
    (docs/live_view.md "Overrides from a forwarded client")."""
    from pymavlink.dialects.v20 import common as mavlink

    s = c.served
    assert s is not None
    s.wait_for(r"forwarding MAVLink to ")
    mav = mavlink.MAVLink(None, srcSystem=254, srcComponent=190)
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    text, sysid = "", None
    end = time.monotonic() + 90
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", c.extra["ports"][0]))
        sock.settimeout(1.0)
        while time.monotonic() < end and not text.endswith("first"):
            try:
                data, peer = sock.recvfrom(65536)
            except TimeoutError:
                continue
            for m in parser.parse_buffer(data) or []:
                kind = m.get_type()
                if kind == "HEARTBEAT" and sysid is None and m.get_srcSystem() != 255:
                    sysid = m.get_srcSystem()
                elif kind == "STATUSTEXT" and m.get_srcSystem() == sysid:
                    if m.text.startswith("phireman:"):
                        text = m.text
                    elif text:
                        text += m.text
            if sysid is not None and not text:  # RTL (ArduCopter 6), again until refused
                sock.sendto(mavlink.MAVLink_set_mode_message(sysid, 1, 6).pack(mav), peer)
    c.expect(
        text == f"phireman: vehicle {sysid} is flown by the relay plan; hold it on the station "
        "first",
        f"no refusal STATUSTEXT from the vehicle (got {text!r})",
    )

    def after() -> None:
        events = c.run_dirs("runs")[-1] / "events.jsonl"
        c.expect(events.is_file(), "no events.jsonl")
        recs = [json.loads(l) for l in events.read_text().splitlines() if l.strip()]
        c.expect(
            any(r.get("action") == "override-refused" and r.get("sysid") == sysid for r in recs),
            "the refusal is not in events.jsonl",
        )

    c.extra["after"] = after


def forward_ports(*kinds: str) -> tuple[str, Callable[[re.Match], str]]:
    """Rewrite every --forward URL's port to a free one (fixed ports are never used in tests)."""

    def repl(m: re.Match) -> str:
        kind = m.group(1)
        port = _free_port(socket.SOCK_STREAM if kind == "tcpin" else socket.SOCK_DGRAM)
        host = "127.0.0.1" if kind == "udpout" else m.group(2)
        return f"--forward {kind}:{host}:{port}"

    return (r"--forward (udpout|udpin|tcpin):([\d.]+):\d+", repl)


def emulate_ports(c: Ctx) -> None:
    """The --gcs address must be outside the vehicles' own ports (issue 28 point 2)."""
    c.has(r"emulating 10 ardupilot vehicle\(s\)|emulating 3 ardupilot vehicle\(s\)")
    m = re.search(r"on udp [\d.]+:(\d+)\.\.(\d+)", c.text())
    c.expect(m, "no port range printed")
    assert m is not None
    gcs = int(re.search(r"--gcs udpout:[\d.]+:(\d+)", c.cmd).group(1))  # type: ignore[union-attr]
    lo, hi = int(m.group(1)), int(m.group(2))
    c.expect(not lo <= gcs <= hi, f"--gcs port {gcs} is one of the vehicles' ports {lo}..{hi}")


def emulate_base_pair() -> tuple[str, Callable[[re.Match], str]]:
    """--base-port 14560 ... udpout:...:14550 -> free ports B ... G (the documented layout: the
    station's port outside the vehicles')."""

    def repl(m: re.Match) -> str:
        base, gcs = _free_port(socket.SOCK_DGRAM), _free_port(socket.SOCK_DGRAM)
        return m.group(0).replace("14560", str(base)).replace("14550", str(gcs))

    return (r"--base-port 14560.*udpout:127\.0\.0\.1:14550", repl)


#: Free ports of the documented emulator + station pair (vehicles' base port, station's port).
_EMU_PAIR = (_free_port(socket.SOCK_DGRAM), _free_port(socket.SOCK_DGRAM))


def version(c: Ctx) -> None:
    c.expect(re.fullmatch(r"phireman \d+\.\d+\.\d+ git [0-9a-f]{12}(\+dirty)? src [0-9a-f]{12}\n", c.out), "version")  # fmt: skip


def mission_list(c: Ctx) -> None:
    readme = (ROOT / "README.md").read_text()
    shipped = re.search(r"Shipped missions \(usable by name\): (.*?)\.\n", readme, re.S)
    assert shipped is not None
    for name in re.findall(r"`(\w+)`", shipped.group(1)):
        c.expect(re.search(rf"^{name}\s", c.out, re.M), f"{name} not listed")


def check_ok(c: Ctx) -> None:
    c.expect(c.out.startswith("OK:"), "check did not say OK")


def emulate_mux(c: Ctx) -> None:
    c.has(
        r"emulating 500 ardupilot vehicle\(s\) in 2 MAVLink network\(s\) on udp [\d.]+:(\d+)\.\.\d+"
    )
    m = re.search(r"on udp [\d.]+:(\d+)\.\.(\d+)", c.text())
    assert m is not None
    base = int(re.search(r"--base-port (\d+)", c.cmd).group(1))  # type: ignore[union-attr]
    ports = (int(m.group(1)), int(m.group(2)))
    c.expect(ports == (base, base + 1), f"--mux: ports {ports}, not one per network from {base}")
    c.has(r"stopped at t = \d")


_HOME_TILE = "tiles/paradise/15/5000/12000.png"

README_FLY_FIRST = (
    "python3.11 -m venv .venv && .venv/bin/pip install -q . && .venv/bin/phireman fly"
)

TABLE: dict[str, Case] = {
    # ---- install and the test suite (README's first lines) ------------------------------------
    README_FLY_FIRST: SKIP(
        "installs phireman into a new venv: .ci/run executes this installation; its `phireman "
        "fly` is run below as the entry 'phireman fly'"
    ),
    "python3.11 -m venv .venv && .venv/bin/pip install -q -e '.[test]' && .venv/bin/python -m pytest -q": SKIP(  # noqa: E501
        "runs the whole test suite, this test included: it is .ci/run's own command"
    ),
    "python3.11 -m venv /tmp/mpvenv && /tmp/mpvenv/bin/pip install MAVProxy": SKIP(
        "installs a third-party tool (MAVProxy) from the network"
    ),
    # ---- version strings quoted from reports (program output, not commands) -----------------
    "phireman 0.1.0 git 077439de8163+dirty src 9d800f353dce": SKIP("output quoted (a version)"),
    "phireman 0.1.0 git 9ff1a02b16f9 src 8c0460b0168b": SKIP("output quoted (a version)"),
    "phireman 0.1.0 git 7b815c3caa61+dirty src c894d49c126f": SKIP("output quoted (a version)"),
    "phireman 0.1.0 git 29204addc8eb src d51d5831716e": SKIP("output quoted (a version)"),
    "phireman --version": Case(check=version),
    # ---- mentions of a subcommand in prose: its --help lists every documented flag ------------
    **{
        m: Case(kind="help")
        for m in (
            "phireman fly [MISSION]",
            "phireman sweep",
            "phireman report",
            "phireman tune",
            "phireman emulate",
            "phireman check",
            "phireman replay",
            "phireman sitl",
            "phireman sitl --mission",
            "phireman sim --mission",
            "phireman fly --serve",
            "phireman replay RUN_DIR --serve",
            "phireman sim --mission M --out DIR",
            "phireman fly --apply-failsafes",
            "phireman sweep --grid paper-table",
        )
    },
    # ---- sim ---------------------------------------------------------------------------------
    "phireman sim": Case(rewrite=(TINY_SIM,), check=sim_header(r"size S", r"2 seeds", "phireman")),
    "phireman sim --size M --info central --seeds 30": Case(
        rewrite=((r"--seeds 30", "--seeds 2"), STEPS_20), check=sim_header("size M", "2 seeds")
    ),
    "phireman sim --size M --info central --seeds 20": Case(
        rewrite=((r"--seeds 20", "--seeds 2"), STEPS_20), check=sim_header("size M", "2 seeds")
    ),
    "phireman sim --method mccst --attrition 2%": Case(
        rewrite=(TINY_SIM,), check=sim_header(r"(?m)^mccst \|", r"attrition 2 %/step")
    ),
    "phireman sim --size S --attrition 0.01 --info central": Case(
        rewrite=(TINY_SIM,), check=sim_header("size S", r"attrition 1 %/step")
    ),
    "phireman sim --set step_size=0.3 --set max_speed_m_s=0.2 --out runs/s1": Case(
        rewrite=(TINY_SIM,),
        check=lambda c: (
            sim_header()(c),
            [c.file(f"runs/s1/{f}") for f in ("runs.csv", "fig2_timeseries.png", "frames.png")],
            c.expect(
                '"step_size": 0.3' in c.file("runs/s1/summary.json").read_text()
                and '"max_speed_m_s": 0.2' in c.file("runs/s1/summary.json").read_text(),
                "--set not recorded in summary.json",
            ),
        ),
    ),
    "phireman sim --mission wildfire_2h": Case(
        # Two hours of mission with batteries in process (one seed, ~6 s of CPU).
        check=lambda c: c.has(r"\d+ rotations", r"0 landed away from the base"),
        timeout=900,
    ),
    "phireman sim --mission wildfire_2h --rotation off": Case(
        # Without rotation the firmware's low-battery failsafe is what brings drones home.
        check=lambda c: c.has(r"0 rotations", r"[1-9]\d* battery failsafes in the air"),
        timeout=900,
    ),
    "phireman sim --mission canyon --terrain-aware ...": Case(kind="help"),
    "phireman sim --mission canyon --out runs/canyon && phireman replay runs/canyon": Case(
        rewrite=(FEW_FRAMES,),
        check=lambda c: (
            sim_mission_then_replay("runs/canyon")(c),
            c.file("runs/canyon/link_profiles.png"),
        ),
    ),
    "phireman replay runs/canyon --serve 8080": Case(
        kind="serve",
        pre=("phireman sim --mission canyon --out runs/canyon",),
        rewrite=(PORT_0,),
        check=terrain_page,
    ),
    "phireman fly canyon --apply-failsafes": Case(
        # 20 s of the canyon through the station: altitudes over the DEM, ArduPilot's terrain
        # requests answered (docs/terrain.md §6).
        rewrite=(SHORT_FLY_NOWAIT,),
        check=lambda c: c.has(
            r"over the terrain: 0 crashes into the ground",
            r"terrain served to the vehicles: [1-9]\d* TERRAIN_REQUEST answered",
        ),
        timeout=600,
    ),
    # The indented blocks of docs/terrain.md (§3, §6): each shortened, run as a user runs it.
    "phireman check canyon": Case(check=lambda c: c.has(r"OK: canyon: 40 emulated")),
    "phireman sim --mission canyon --seeds 3": Case(
        rewrite=(SEEDS_TO_1,), check=lambda c: c.has(r"terrain-aware on: 0 crashes", r"TU1 = ")
    ),
    "phireman sim --mission canyon --seeds 3 --terrain-aware off": Case(
        rewrite=(SEEDS_TO_1,), check=lambda c: c.has(r"terrain-aware off: 0 crashes", r"TU1 = ")
    ),
    "phireman sim --mission canyon --terrain-aware altitude": Case(
        check=lambda c: c.has(r"terrain-aware altitude: 0 crashes", r"TU1 = ")
    ),
    "phireman fly canyon --apply-failsafes --duration-s 120": Case(
        rewrite=((r"--duration-s 120", "--duration-s 10 --speedup 60 --no-wait"),),
        check=lambda c: c.has(r"over the terrain: 0 crashes into the ground"),
        timeout=600,
    ),
    "phireman fly canyon --apply-failsafes --personality px4 --duration-s 120": Case(
        rewrite=((r"--duration-s 120", "--duration-s 10 --speedup 60 --no-wait"),),
        check=lambda c: c.has(r"40 emulated px4 drones", r"over the terrain: 0 crashes"),
        timeout=600,
    ),
    "phireman fly canyon --apply-failsafes --seed 1 --speedup 20": Case(
        rewrite=((r"--speedup 20", "--speedup 60 --duration-s 10 --no-wait"),),
        check=lambda c: c.has(r"over the terrain: 0 crashes into the ground"),
        timeout=600,
    ),
    "phireman fly canyon --apply-failsafes --seed 1 --personality px4 --speedup 20": Case(
        rewrite=((r"--speedup 20", "--speedup 60 --duration-s 10 --no-wait"),),
        check=lambda c: c.has(r"40 emulated px4 drones", r"over the terrain: 0 crashes"),
        timeout=600,
    ),
    ".venv/bin/python bench/terrain_canyon.py --seeds 100": Case(kind="bench"),
    ".venv/bin/python bench/terrain_canyon.py --seeds 100 --mission canyon_camp": Case(
        kind="bench"
    ),
    ".venv/bin/python bench/terrain_canyon.py --seeds 100 --mission canyon_deep": Case(
        kind="bench"
    ),
    "phireman sim --mission canyon --terrain-aware off": Case(
        check=lambda c: c.has(r"terrain-aware off: 0 crashes", r"TU1 = ")
    ),
    # ---- TAK (docs/tak.md) ----------------------------------------------------------------------
    "phireman -v": Case(check=lambda c: c.has(r"-v, --verbose")),
    "phireman check mission.yaml": Case(
        pre=(
            "printf 'name: tak-demo\\ntasks:\\n"
            "  - {name: Alpha, tak: {callsign: ALPHA}}\\n"
            '  - {name: Engine, tak: {callsign_pattern: "ENGINE-*", slots: 3}}\\n'
            "  - {track: [{t_s: 0, north_m: 50, east_m: 0}]}\\n' > mission.yaml",
        ),
        check=lambda c: c.has(r"^OK: tak-demo", r"tak"),
    ),
    "phireman fly --tak": Case(kind="help"),
    "phireman fly --tak URL": Case(kind="help"),
    "phireman fly mission.yaml --tak tcp://tak.example:8087": SKIP(
        "tak.example is a placeholder TAK server; the exchange through FreeTAKServer runs in "
        "tests/integration/test_tak_server.py when PHIREMAN_FTS_PYTHON points at one"
    ),
    "phireman fly mission.yaml --tak tls://tak.example:8089 --tak-tls-client-cert me.pem --tak-tls-client-key me.key --tak-tls-client-cafile ca.pem": SKIP(  # noqa: E501
        "tak.example and the certificates are placeholders: a TLS TAK server with a client "
        "certificate is not available here"
    ),
    "phireman fly mission.yaml --tak udp+ro://127.0.0.1:4242 --tak udp+wo://127.0.0.1:4243": SKIP(
        "needs TAK clients on those ports: the same command, with pytak clients moving two crews, "
        "runs end to end in tests/integration/test_tak_udp.py"
    ),
    "phireman fly mission.yaml --tak udp://239.2.3.1:6969": SKIP(
        "multicast leaves loopback for the machine's network: never sent by tests"
    ),
    "python3.11 -m venv /opt/fts-venv": SKIP(
        "installs FreeTAKServer outside the project (docs/tak.md); its test runs when "
        "PHIREMAN_FTS_PYTHON points at that venv"
    ),
    # ---- endurance (docs/results/endurance.md): 2 seeds of the 100 --------------------------------
    "phireman sim --mission wildfire_2h --seeds 100 --seed 0 --no-progress": Case(
        rewrite=(SEEDS_TO_2,),
        check=lambda c: c.has(r"rotations [\d.]+ per run", r"landed away from the base 0 "),
        timeout=900,
    ),
    "phireman sim --mission wildfire_2h --seeds 100 --seed 0 --no-progress --battery unlimited": Case(
        rewrite=(SEEDS_TO_2,), check=lambda c: c.has(r"TU1 = "), timeout=900
    ),
    "phireman sim --mission wildfire_2h --seeds 100 --seed 0 --no-progress --rotation off": Case(
        rewrite=(SEEDS_TO_2,),
        check=lambda c: c.has(r"rotations 0\.0 per run", r"battery failsafes in the air [1-9]"),
        timeout=900,
    ),
    ".venv/bin/python bench/bench_endurance.py --seeds 0": Case(kind="bench"),
    "phireman fly wildfire_2h --duration-s 2400 --speedup 50 --apply-failsafes": Case(
        # The first 60 s of the 2,400: batteries read, the battery failsafes applied, K planned.
        rewrite=((r"--duration-s 2400", "--duration-s 60"), (r"$", " --no-wait --out runs")),
        check=lambda c: c.has(
            r"TU1/TU2 as the station saw them",
            r"BATT_FS_LOW_ACT",
            r"relay rotation: \d+ rotations, \d+ battery failsafes in the air, \d+ landed away",
        ),
        timeout=600,
    ),
    "phireman fly wildfire_2h --seed 1 --speedup 50 --apply-failsafes": Case(
        # The first 60 s of the two hours (the whole flight is docs/results/endurance.md's).
        rewrite=(
            (r"--speedup 50", "--duration-s 60 --speedup 50"),
            (r"$", " --no-wait --out runs"),
        ),
        check=lambda c: c.has(r"TU1/TU2 as the station saw them", r"BATT_FS_LOW_ACT"),
        timeout=600,
    ),
    "phireman fly wildfire_2h --personality px4 --seed 1 --speedup 50 --apply-failsafes": Case(
        # PX4's battery failsafe applied (COM_LOW_BAT_ACT 0 -> 3) and the first 60 s flown.
        rewrite=(
            (r"--speedup 50", "--duration-s 60 --speedup 50"),
            (r"$", " --no-wait --out runs"),
        ),
        check=lambda c: c.has(r"TU1/TU2 as the station saw them", r"COM_LOW_BAT_ACT"),
        timeout=600,
    ),
    ".venv/bin/python bench/bench_endurance_flight.py": Case(kind="bench"),
    ".venv/bin/python bench/bench_endurance_flight.py --personality px4": Case(kind="bench"),
    ".venv/bin/python bench/bench_endurance_flight.py --skip-short --record /tmp/wildfire_2h.pkl": Case(  # noqa: E501
        kind="bench"
    ),
    ".venv/bin/python bench/bench_endurance_flight.py --replay /tmp/wildfire_2h.pkl": Case(
        kind="bench"
    ),
    ".venv/bin/python bench/bench_endurance_flight.py --replay /tmp/wildfire_2h.pkl --no-kernels": Case(  # noqa: E501
        kind="bench"
    ),
    "phireman sweep --help": Case(check=lambda c: c.has(r"usage: phireman sweep", r"--scheduler")),
    "phireman sweep --grid custom --size XS --attrition 0 1% --method phireman dccrs --seeds 3 --chunk 1 --scheduler sched.json --store cluster.sqlite": SKIP(  # noqa: E501
        "needs a Dask scheduler and workers started first: run with them, a worker killed "
        "mid-sweep, by tests/mission/test_sweep_dask_cluster.py"
    ),
    "phireman sweep --grid paper-table --scheduler tcp://HEAD:8786 --store results.sqlite": SKIP(
        "HEAD is a placeholder for the cluster's head node"
    ),
    "phireman sim --mission wildfire --out runs/wf": Case(
        check=lambda c: [c.file(f"runs/wf/{f}") for f in ("truth.npz", "metrics.csv")]
    ),
    "phireman sim --mission wildfire --out runs/wf && phireman replay runs/wf": Case(
        rewrite=(FEW_FRAMES,), check=sim_mission_then_replay("runs/wf")
    ),
    "phireman sim --mission wildfire --out runs/wildfire && phireman replay runs/wildfire": Case(
        rewrite=(FEW_FRAMES,), check=sim_mission_then_replay("runs/wildfire")
    ),
    "phireman sim --mission wildfire --out /tmp/wf && phireman replay /tmp/wf --out docs/examples/wildfire --max-frames 60": Case(  # noqa: E501
        rewrite=((r"/tmp/", "tmp/"), (r"--max-frames 60", "--max-frames 6")),
        check=sim_mission_then_replay("tmp/wf", out="docs/examples/wildfire", frames=6),
    ),
    # ---- replay ------------------------------------------------------------------------------
    "phireman replay runs/wf": Case(
        fixture=(("sim", "runs/wf"),), rewrite=(FEW_FRAMES,), check=newest_replayed("runs")
    ),
    "phireman replay runs/wildfire --out /tmp/plots --animation none": Case(
        fixture=(("sim", "runs/wildfire"),),
        rewrite=((r"/tmp/", "tmp/"),),
        check=lambda c: pictures(c, "tmp/plots", frames=None),
    ),
    "phireman replay runs": Case(
        # the newest run is the one written last (its truth.npz): touched after the copies
        pre=("touch runs/20991231-000000-newest/truth.npz",),
        fixture=(("sim", "runs/older"), ("fly", "runs/20991231-000000-newest")),
        rewrite=(FEW_FRAMES,),
        check=lambda c: (
            c.has(r"replaying the newest, 20991231-000000-newest"),
            pictures(c, "runs/20991231-000000-newest"),
            c.expect(not (c.cwd / "runs/older/frames.png").exists(), "replayed the older run"),
        ),
    ),
    "phireman replay DIR": Case(
        fixture=(("fly", "DIR"),), rewrite=(FEW_FRAMES,), check=lambda c: pictures(c, "DIR")
    ),
    "phireman replay RUN_DIR": Case(
        fixture=(("fly", "RUN_DIR"),),
        rewrite=(FEW_FRAMES,),
        check=lambda c: pictures(c, "RUN_DIR"),
    ),
    "phireman replay RUN --out docs/examples/fly": Case(
        fixture=(("fly", "RUN"),),
        rewrite=(FEW_FRAMES,),
        check=lambda c: pictures(c, "docs/examples/fly"),
    ),
    "phireman replay RUN_DIR --serve 8080": Case(
        kind="serve", fixture=(("fly", "RUN_DIR"),), rewrite=(PORT_0,), check=replay_page
    ),
    "phireman replay runs/20261202-...-fly-wildfire-emulated-s1 --serve 8080": Case(
        kind="serve",
        fixture=(("fly", "runs/20261202-...-fly-wildfire-emulated-s1"),),
        rewrite=(PORT_0,),
        check=replay_page,
    ),
    "phireman replay RUN_DIR --export geojson --at 60 --at 120": Case(
        fixture=(("fly", "RUN_DIR"),), check=export_geojson("RUN_DIR/export.geojson", (60, 120))
    ),
    "phireman replay RUN_DIR --export kml --out /tmp/wildfire.kml": Case(
        fixture=(("fly", "RUN_DIR"),),
        rewrite=((r"/tmp/", "tmp/"),),
        check=export_kml("tmp/wildfire.kml"),
    ),
    # ---- fly (the emulator) ------------------------------------------------------------------
    "phireman fly": Case(rewrite=(SHORT_FLY,), check=fly_run()),
    "phireman fly --personality px4": Case(
        rewrite=(SHORT_FLY_NOWAIT,), check=fly_run(personality="px4")
    ),
    "phireman fly wildfire --personality px4 --seed 3": Case(
        rewrite=(SHORT_FLY_NOWAIT,), check=fly_run(personality="px4", seed=3)
    ),
    "phireman fly hazard_zone --out runs/hz && phireman replay runs/hz": Case(
        rewrite=((r"(--out runs/hz)", r"\1 --duration-s 20 --speedup 60 --no-wait"), FEW_FRAMES),
        check=lambda c: (
            fly_run("runs/hz")(c),
            newest_replayed("runs/hz")(c),
            c.has("replaying runs/hz/"),
        ),
    ),
    "phireman fly --serve 8080": Case(kind="serve", rewrite=(PORT_0,), check=page()),
    "phireman fly wildfire --serve 8080": Case(kind="serve", rewrite=(PORT_0,), check=page()),
    # ---- the relay rotation on the page (docs/live_view.md, docs/design/endurance.md §8) --------
    "phireman fly --swap-confirm": Case(kind="help"),
    "phireman fly wildfire_2h --serve 8080 --apply-failsafes": Case(
        kind="serve", rewrite=(PORT_0,), check=rotation_page("auto")
    ),
    "phireman fly wildfire_2h --serve 8080 --apply-failsafes --swap-confirm manual": Case(
        kind="serve", rewrite=(PORT_0,), check=rotation_page("manual")
    ),
    "phireman fly wildfire --serve 0.0.0.0:8080": Case(
        kind="serve", rewrite=(PORT_0,), check=page(public=True)
    ),
    "phireman fly wildfire --serve 8080 --alert-crew-after 30": Case(
        kind="serve", rewrite=(PORT_0,), check=page()
    ),
    "phireman fly wildfire --serve 8080 --serve-actions off": Case(
        kind="serve", rewrite=(PORT_0,), check=page(actions=False)
    ),
    "phireman fly wildfire --serve 8080 --tiles ~/tiles/paradise": Case(
        kind="serve", rewrite=(PORT_0,), pre=("tile",), check=page(tiles="tiles")
    ),
    "phireman fly wildfire --serve 8080 --tiles 'https://tiles.example/{z}/{x}/{y}.png'": Case(
        kind="serve",
        rewrite=(PORT_0,),
        check=page(tiles="https://tiles.example/{z}/{x}/{y}.png"),
    ),
    "phireman fly wildfire --serve 8080 --forward udpout:127.0.0.1:14550": Case(
        kind="serve",
        rewrite=(PORT_0, forward_ports()),
        check=forwarding(("udpout",), readonly=False, serve=True),
    ),
    "phireman fly wildfire --forward udpout:127.0.0.1:14550 --serve 8080": Case(
        kind="serve",
        rewrite=(PORT_0, forward_ports()),
        check=forwarding(("udpout",), readonly=False, serve=True),
    ),
    "phireman fly wildfire --forward udpout:127.0.0.1:14550": Case(
        kind="serve", rewrite=(forward_ports(),), check=forwarding(("udpout",), readonly=False)
    ),
    "phireman fly wildfire --forward tcpin:0.0.0.0:5763 --forward-readonly": Case(
        kind="serve", rewrite=(forward_ports(),), check=forwarding(("tcpin",), readonly=True)
    ),
    "phireman fly wildfire --forward udpin:0.0.0.0:14551 --forward-readonly": Case(
        kind="serve", rewrite=(forward_ports(),), check=forwarding(("udpin",), readonly=True)
    ),
    "phireman fly wildfire --forward udpout:127.0.0.1:14550 --forward-overrides refuse": Case(
        kind="serve", rewrite=(forward_ports(),), check=forward_refusal
    ),
    "phireman fly wildfire --forward udpout:192.0.2.10:14550 --forward tcpin:0.0.0.0:5763": Case(
        kind="serve",
        rewrite=(forward_ports(),),
        check=forwarding(("udpout", "tcpin"), readonly=False),
    ),
    # ---- fly against real autopilots / firmware: cannot run here ----------------------------
    "phireman fly mission.yaml --connect udpin:0.0.0.0:14550 --connect udpin:0.0.0.0:14560": SKIP(
        "real autopilots on UDP 14550/14560 (hardware or your SITL); mission.yaml is the user's"
    ),
    "phireman fly real_links_template --connect udpin:0.0.0.0:14550": SKIP(
        "real vehicles: the template must be edited first (origin, links, sysids)"
    ),
    "phireman fly sitl_ardupilot --apply-failsafes": SKIP(
        "needs the ArduCopter SITL vehicles of 'phireman sitl ardupilot' (a firmware build, "
        "not shipped; tests/integration/test_sitl.py flies it when PHIREMAN_ARDUCOPTER is set)"
    ),
    ".venv/bin/python -m pytest tests/integration/test_sitl_rotation.py -s": SKIP(
        "needs ArduCopter SITL / PX4 SIH builds (not shipped; PHIREMAN_ARDUCOPTER / PHIREMAN_PX4); "
        "without them the test skips itself, with them it is the suite's own SITL test"
    ),
    "phireman fly sitl_px4 --apply-failsafes": SKIP(
        "needs the PX4 SITL vehicles of 'phireman sitl px4' (a firmware build, not shipped; "
        "tests/integration/test_sitl.py flies it when PHIREMAN_PX4 is set)"
    ),
    **{
        c: SKIP("an ArduCopter / PX4 SITL build (not shipped; PHIREMAN_ARDUCOPTER / PHIREMAN_PX4)")
        for c in (
            "phireman sitl ardupilot --vehicles 3 --mission sitl_ardupilot --binary ~/ardupilot/build/sitl/bin/arducopter",  # noqa: E501
            "phireman sitl px4 --vehicles 3 --mission sitl_px4 --binary ~/PX4-Autopilot/build/px4_sitl_default/bin/px4",  # noqa: E501
            "phireman sitl ardupilot --vehicles 3 --mission sitl_ardupilot",
            "phireman sitl px4 --vehicles 3 --mission sitl_px4 --print-fly",
            "phireman sitl ardupilot --vehicles 3 --speedup 5",
        )
    },
    **{
        c: SKIP(
            "mission files of that measurement session (/tmp/rally/m/, not in the repository) and "
            "placeholders S / DIR from a loop (docs/results/resilient_flight.md)"
        )
        for c in (
            "nice -n 10 phireman fly /tmp/rally/m/wildfire_phireman.yaml --seed S --out DIR --no-wait",  # noqa: E501
            "nice -n 10 phireman fly /tmp/rally/m/wildfire_resilient.yaml --seed S --out DIR --no-wait",  # noqa: E501
            "nice -n 10 phireman fly /tmp/rally/m/wildfire_norally.yaml --seed S --out DIR --no-wait",  # noqa: E501
        )
    },
    # ---- sweep -------------------------------------------------------------------------------
    "phireman sweep --grid paper-table --dry-run": Case(check=sweep_store("x", 7500, dry=True)),
    "phireman sweep --grid paper-table --store results.sqlite": Case(
        rewrite=((r"$", " --size XS --attrition 0 --seeds 1 --set n_steps=20"),),
        check=sweep_store("results.sqlite", 3),
    ),
    "phireman sweep --grid paper-ablations --store results.sqlite --workers 2": Case(
        rewrite=((r"$", " --seeds 1 --set n_steps=20"),), check=sweep_store("results.sqlite", 7)
    ),
    "phireman sweep --grid custom --size XS S --attrition 0 1% --method phireman --seeds 10 --set n_steps=50 --store quick.sqlite": Case(  # noqa: E501
        rewrite=(SEEDS_TO_1,), check=sweep_store("quick.sqlite", 4)
    ),
    "phireman sweep --grid paper-table --executor dask --scheduler tcp://10.0.0.5:8786 --store results.sqlite": SKIP(  # noqa: E501
        "needs a running Dask cluster at tcp://10.0.0.5:8786 (the executor itself is tested "
        "in tests/mission/test_sweep.py)"
    ),
    "phireman sweep --grid custom --size XS S --attrition 0 1% 2% --method phireman dccrs mccst --seeds 10 --store small.sqlite": Case(  # noqa: E501
        rewrite=(SEEDS_TO_1, STEPS_20), check=sweep_store("small.sqlite", 18)
    ),
    "phireman sweep --grid paper-table --store fresh.sqlite --workers 2 --no-progress": Case(
        rewrite=((r"$", " --size XS --attrition 0 --seeds 1 --set n_steps=20"),),
        check=sweep_store("fresh.sqlite", 3),
    ),
    "phireman sweep --grid paper-ablations --store fresh.sqlite --workers 2 --no-progress": Case(
        rewrite=((r"$", " --seeds 1 --set n_steps=20"),), check=sweep_store("fresh.sqlite", 7)
    ),
    "phireman sweep --grid paper-table --methods phireman --sizes S M --store paper.sqlite": Case(
        rewrite=((r"$", " --attrition 0 --seeds 1 --set n_steps=20"),),
        check=sweep_store("paper.sqlite", 2),
    ),
    "phireman sweep --grid custom --methods phireman-central --sizes S --attrition 0 0.005 0.01 0.02 0.05 --seeds 100 --store info.sqlite": Case(  # noqa: E501
        rewrite=(SEEDS_TO_1, STEPS_20), check=sweep_store("info.sqlite", 5)
    ),
    "phireman sweep --grid paper-table --store paper.sqlite": Case(
        rewrite=((r"$", " --size XS --attrition 0 --seeds 1 --set n_steps=20"),),
        check=sweep_store("paper.sqlite", 3),
    ),
    "phireman sweep --grid paper-ablations --store paper.sqlite": Case(
        rewrite=((r"$", " --seeds 1 --set n_steps=20"),), check=sweep_store("paper.sqlite", 7)
    ),
    "phireman sweep --grid custom --methods phireman-central --sizes XS S M --seeds 100 ...": SKIP(
        "abridged in the text ('...'): the full line is docs/results/resilient.md's loop, run below"
    ),
    # the loop bodies of docs/results/resilient.md, with the loops' first values
    "phireman sweep --grid custom --method phireman-resilient --seeds 100 --size $1 --attrition $2 --set $v --set base_view=oracle --store resilient.sqlite --workers 2": Case(  # noqa: E501
        rewrite=((r"\$1", "XS"), (r"\$2", "0.01"), (r"\$v", "claim_gain=0"), SEEDS_TO_1, STEPS_20),
        check=sweep_store("resilient.sqlite", 1),
    ),
    "phireman sweep --grid custom --size XS S M L XL --attrition 0 0.5% 1% 2% 5% --method phireman-resilient --seeds 100 --store resilient.sqlite --workers 2 --set base_view=oracle": Case(  # noqa: E501
        rewrite=((r"--attrition 0 0\.5% 1% 2% 5%", "--attrition 0"), SEEDS_TO_1, STEPS_20),
        check=sweep_store("resilient.sqlite", 5),
    ),
    "phireman sweep --grid custom --size XS S M L XL --attrition 0 0.5% 1% 2% 5% --method phireman-resilient --seeds 100 --store resilient_heard.sqlite --workers 2": Case(  # noqa: E501
        rewrite=((r"--attrition 0 0\.5% 1% 2% 5%", "--attrition 0"), SEEDS_TO_1, STEPS_20),
        check=sweep_store("resilient_heard.sqlite", 5),
    ),
    "phireman sweep --grid custom --method phireman-central --seeds 100 --size $1 --attrition $2 --store central.sqlite": Case(  # noqa: E501
        rewrite=((r"\$1", "XS"), (r"\$2", "0.01"), SEEDS_TO_1, STEPS_20),
        check=sweep_store("central.sqlite", 1),
    ),
    "phireman sweep --grid custom --method phireman-resilient --seeds 100 --size $1 --attrition $2 --set info=central --store central.sqlite": Case(  # noqa: E501
        rewrite=((r"\$1", "XS"), (r"\$2", "0.01"), SEEDS_TO_1, STEPS_20),
        check=sweep_store("central.sqlite", 1),
    ),
    # ---- report ------------------------------------------------------------------------------
    "phireman report results.sqlite --out report/": Case(
        pre=(
            "phireman sweep --grid paper-table --size XS --attrition 0 --seeds 2 --set n_steps=20 --store results.sqlite --no-progress",
        ),  # noqa: E501
        rewrite=((r"$", " --no-progress"),),
        check=report_written("report/"),
    ),
    "phireman report small.sqlite --out docs/examples/report": Case(
        pre=(
            "phireman sweep --grid custom --size XS --attrition 0 --method phireman dccrs mccst --seeds 2 --set n_steps=20 --store small.sqlite --no-progress",
        ),  # noqa: E501
        rewrite=((r"$", " --no-progress"),),
        check=report_written("docs/examples/report"),
    ),
    "phireman report quick.sqlite --out /tmp/r --set n_steps=50 --notes docs/misses.md": Case(
        pre=(
            "phireman sweep --grid custom --size XS --attrition 0 --method phireman --seeds 2 --set n_steps=50 --store quick.sqlite --no-progress",  # noqa: E501
            "mkdir -p docs && printf '# Misses\\n\\nnotes-marker-28\\n' > docs/misses.md",
        ),
        rewrite=((r"/tmp/", "tmp/"), (r"$", " --no-progress")),
        check=report_written("tmp/r", notes="notes-marker-28"),
    ),
    # ---- tune --------------------------------------------------------------------------------
    "phireman tune --method phireman --grid step_size=0.1,0.2,0.3 --grid max_descent_steps=5,10,20 --seeds 30 --store tune.sqlite --out docs/tuning": Case(  # noqa: E501
        rewrite=(SEEDS_TO_2, STEPS_20), check=tune_record(9, "docs/tuning")
    ),
    "phireman tune --method dccrs --grid leader_gain=0.02,0.05,0.1 --seeds 30 --store tune.sqlite": Case(  # noqa: E501
        rewrite=(SEEDS_TO_2, STEPS_20), check=tune_record(3)
    ),
    "phireman tune --method dccrs --grid leader_exponent=-1,-0.5,0,1 --grid velocity_matching=0.1,0.3,0.5 --seed-start 1000 --seeds 30": Case(  # noqa: E501
        rewrite=(SEEDS_TO_2, STEPS_20), check=tune_record(12)
    ),
    "phireman tune --method dccrs --grid density_target=3,4,6 --grid density_exponent=0.5,1,2 --seed-start 1000 --seeds 30": Case(  # noqa: E501
        rewrite=(SEEDS_TO_2, STEPS_20), check=tune_record(9)
    ),
    "phireman tune --method phireman --grid age_max_steps=3,5,10 --grid dist_max=4,6,10 --grid step_size=0.1,0.2,0.3 --size S --attrition 0.01 --seeds 30 --store /tmp/stub/tune.sqlite --out docs/tuning/phireman_S_1pct.md": Case(  # noqa: E501
        rewrite=((r"/tmp/", "tmp/"), SEEDS_TO_2, STEPS_20),
        pre=("mkdir -p tmp/stub docs/tuning",),
        check=tune_record(27, "docs/tuning/phireman_S_1pct.md"),
    ),
    "phireman tune --method phireman --grid broadcast_after_move=true,false --grid forget_unheard=true,false --grid age_max_steps=3,4 --size S --attrition 0.01 --seeds 30 --store /tmp/tune/msg.sqlite --out docs/tuning/phireman_messages_S_1pct.md": Case(  # noqa: E501
        rewrite=((r"/tmp/", "tmp/"), SEEDS_TO_2, STEPS_20),
        pre=("mkdir -p tmp/tune docs/tuning",),
        check=tune_record(8, "docs/tuning/phireman_messages_S_1pct.md"),
    ),
    "phireman tune --method phireman-resilient --grid redundancy_gain=0,0.2,0.3,0.4 --grid redundancy_reach=8 --size S --attrition 0.01 --seeds 100 --seed 1000 --store tune3.sqlite --workers 2": Case(  # noqa: E501
        rewrite=(SEEDS_TO_2, STEPS_20), check=tune_record(4)
    ),
    "phireman tune --method phireman-resilient --grid redundancy_gain=0.3,0.4,0.6 --grid redundancy_reach=8 --size M --attrition 0.02 --seeds 50 --seed 1000 --store tune3.sqlite --workers 2": Case(  # noqa: E501
        rewrite=(SEEDS_TO_2, STEPS_20), check=tune_record(3)
    ),
    "phireman tune --method phireman-resilient --seed 1000 --store tune2.sqlite --workers 2": Case(
        kind="help"
    ),
    # ---- emulate -----------------------------------------------------------------------------
    "phireman emulate --vehicles 10 --personality ardupilot --home 39.7596,-121.6219,540 --base-port 14560 --gcs udpout:127.0.0.1:14550": Case(  # noqa: E501
        rewrite=(emulate_base_pair(), (r"$", " --duration-s 2")),
        check=emulate_ports,
    ),
    # The documented pair: the emulator in the background (another terminal), the station on it.
    "phireman fly wildfire --connect udpin:127.0.0.1:14550 --vehicles 10": Case(
        pre=(
            f"nohup phireman emulate --vehicles 10 --personality ardupilot --home "
            f"39.7596,-121.6219,540 --base-port {_EMU_PAIR[0]} --gcs udpout:127.0.0.1:"
            f"{_EMU_PAIR[1]} --duration-s 240 > emulate.log 2>&1 &",
        ),
        rewrite=(
            (r"udpin:127\.0\.0\.1:14550", f"udpin:127.0.0.1:{_EMU_PAIR[1]}"),
            (r"$", " --duration-s 10 --no-wait"),
        ),
        check=lambda c: c.has(r"10 drones"),
        timeout=300,
    ),
    "phireman emulate --vehicles 500 --mux --radio-range-m 300 --attrition-per-s 0.0005": Case(
        rewrite=((r"$", lambda m: f" --base-port {_free_port(socket.SOCK_DGRAM)} --duration-s 2"),),
        check=emulate_mux,
    ),
    # ---- check / mission ---------------------------------------------------------------------
    "phireman check my_mission.yaml": Case(
        pre=("phireman mission show wildfire > my_mission.yaml",), check=check_ok
    ),
    "phireman mission new --preset S --attrition 0.01 --unit-m 50 > s.yaml": Case(
        check=mission_yaml("s.yaml", unit_m=50)
    ),
    "phireman mission new --preset S --attrition 0.01 --unit-m 50 > m.yaml": Case(
        check=mission_yaml("m.yaml", unit_m=50)
    ),
    "phireman mission show MISSION": Case(
        rewrite=((r"MISSION$", "wildfire"),), check=mission_yaml(None)
    ),
    "phireman mission list": Case(check=mission_list),
    # ---- python: bench recipes in the measurement records ------------------------------------
    **{
        c: Case(kind="bench")
        for c in (
            "PYTHONPATH=$PWD .venv/bin/python bench/bench_identity.py --baseline /tmp/hz_base --methods phireman phireman-resilient phireman-resilient@central dccrs --cells XS:1 S:1 --seeds 0 1",  # noqa: E501
            ".venv/bin/python bench/compare_backends.py --seeds 1-10 --personality ardupilot px4 --speedup 22",  # noqa: E501
            "python bench/resilient_check.py paper.sqlite --methods phireman --cells XS:1 S:1 M:2 L:5 XL:2 --seeds 0 1",  # noqa: E501
            "python bench/resilient_check.py resilient.sqlite --methods phireman-resilient --cells XS:1 S:1 M:2 L:2 XL:2 --seeds 0 1 --set base_view=oracle",  # noqa: E501
            "python bench/resilient_cpu.py --seeds 0 1",
            "python bench/resilient_heard_table.py --phireman paper.sqlite --oracle resilient.sqlite --heard resilient_heard.sqlite",  # noqa: E501
            "python bench/bench_identity.py --baseline <tree of d936203> --methods phireman dccrs mccst phireman@central dccrs@central --cells XS:1 S:1 M:2 L:5 XL:2 --seeds 0 1 2 --quiet",  # noqa: E501
            "python bench/bench_identity.py --baseline <tree of d936203> --methods phireman-resilient phireman-resilient@central --new-params base_view=oracle --cells XS:1 S:1 M:2 L:2 --seeds 0 1 --quiet",  # noqa: E501
            "python bench/resilient_table.py --baseline paper.sqlite --store resilient.sqlite --ablations XS:1 S:1 M:2 L:2",  # noqa: E501
            "python bench/resilient_table.py --baseline resilient_central.sqlite --base-method phireman-central --store resilient_central.sqlite --new-set info=central",  # noqa: E501
            "python bench/resilient_flights.py --runs /work/flight/runs --seeds 11-20 --mission wildfire phireman=wildfire_phireman.yaml phireman-resilient=wildfire_resilient.yaml --mission hazard_zone phireman=hazard_zone_phireman.yaml phireman-resilient=hazard_zone_resilient.yaml",  # noqa: E501
            ".venv/bin/python bench/bench_fly_loop.py --vehicles 500 --duration-s 150 --speedup 10 --commit ddf8dc3 --repeat 2",  # noqa: E501
            ".venv/bin/python bench/bench_fly_loop.py --vehicles 500 --duration-s 150 --speedup 12",
            ".venv/bin/python bench/bench_fly_loop.py --vehicles 500 --duration-s 150 --speedup 15 --commit ddf8dc3 --repeat 1",  # noqa: E501
            ".venv/bin/python bench/bench_fly_loop.py --vehicles 500 --duration-s 150 --speedup 10",
            ".venv/bin/python bench/bench_fly_loop.py --vehicles 500 --duration-s 40 --speedup 10 --commit 7b1120f --repeat 2",  # noqa: E501
            ".venv/bin/python bench/bench_loop_identity.py --commit 7b1120f",
            ".venv/bin/python bench/bench_fly_loop.py --vehicles 500 --duration-s 60 --speedup 5 --extras-compare --repeat 2",  # noqa: E501
            ".venv/bin/python bench/bench_fly_loop.py --speedup 10 --duration-s 40 --commit 64a57d8 --repeat 2",  # noqa: E501
            ".venv/bin/python bench/bench_emulator.py --px4 500 --telemetry batch --duration-s 10 --ticks 100",  # noqa: E501
            ".venv/bin/python bench/bench_emulator.py --px4 1000 --telemetry batch --duration-s 10 --ticks 100",  # noqa: E501
            ".venv/bin/python bench/bench_emulator.py --ardupilot 500 --telemetry batch --duration-s 10 --ticks 100",  # noqa: E501
            ".venv/bin/python bench/bench_emulator.py --ardupilot 1000 --telemetry batch --duration-s 10 --ticks 100",  # noqa: E501
            ".venv/bin/python bench/bench_emulator.py --px4 1000 --ardupilot 1000 --telemetry batch --duration-s 10 --ticks 100",  # noqa: E501
            ".venv/bin/python bench/bench_emulator.py --px4 1000 --ardupilot 1000 --no-realtime --ticks 100",  # noqa: E501
        )
    },
    "PYTHONPATH=$PWD .venv/bin/python bench/bench_hazard.py run mission/format/examples/hazard_zone.yaml --info central --seeds 0 10 --config phireman phireman '{}' --config off phireman-resilient '{}' --config avoid phireman-resilient '{\"hazard_avoid\": true}' --config push1 phireman-resilient '{\"hazard_push_gain\": 1.0}' --config avoid+push1 phireman-resilient '{\"hazard_avoid\": true, \"hazard_push_gain\": 1.0}' --config avoid+push3 phireman-resilient '{\"hazard_avoid\": true, \"hazard_push_gain\": 3.0}' > central.jsonl": Case(  # noqa: E501
        kind="bench", help_args=("bench/bench_hazard.py", "run")
    ),
    "PYTHONPATH=$PWD .venv/bin/python bench/bench_hazard.py summary central.jsonl async.jsonl": Case(
        kind="bench", help_args=("bench/bench_hazard.py", "summary")
    ),
    **{
        c: SKIP(
            "a scratch script the page writes to /tmp with a heredoc (docs/tuning/"
            "mccst_calibration.md §3): a record of that calibration, not a command of the repository"
        )
        for c in (
            ".venv/bin/python /tmp/mccst_calib.py default '{}'",
            ".venv/bin/python /tmp/mccst_calib.py A '{\"k_p\": 1.0}'",
            '.venv/bin/python /tmp/mccst_calib.py B \'{"k_p": 1.0, "gamma": 1.0, "kappa": 0.9}\'',
            ".venv/bin/python /tmp/mccst_calib.py balanced \"$(.venv/bin/python -c 'import json; from planner.mccst import BALANCED_PARAMS as b; print(json.dumps(b))')\"",  # noqa: E501
            ".venv/bin/python /tmp/mccst_calib.py strong \"$(.venv/bin/python -c 'import json; from planner.mccst import STRONG_PARAMS as s; print(json.dumps(s))')\"",  # noqa: E501
            ".venv/bin/python /tmp/mccst_calib.py x '{\"k_p\": 0.03}' S 8",
        )
    },
}


# ----------------------------------------------------------------------------------------------
# Running
# ----------------------------------------------------------------------------------------------


def _flags(cmd: str) -> list[str]:
    return re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", cmd)


def rewritten(cmd: str, case: Case) -> str:
    """``cmd`` after the case's rewrites; each must apply, and no documented flag may go."""
    out = cmd
    for pat, repl in case.rewrite:
        new, n = re.subn(pat, repl, out)
        assert n >= 1, f"rewrite /{pat}/ no longer applies to {cmd!r}: update the table"
        out = new
    for flag in _flags(cmd):
        assert flag in _flags(out), f"rewrite removed the documented {flag} from {cmd!r}"
    return out


class Fixtures:
    """The shared runs (built once, in the background, by the documented commands themselves)."""

    def __init__(self, base: Path) -> None:
        self.base = base
        self.pool = ThreadPoolExecutor(2)
        self._futures: dict[str, Future[Path]] = {}
        self._lock = threading.Lock()

    def get(self, name: str) -> Path:
        with self._lock:
            if name not in self._futures:
                self._futures[name] = self.pool.submit(self._build, name)
        return self._futures[name].result()

    def _build(self, name: str) -> Path:
        d = self.base / name
        d.mkdir()
        if name == "fly":  # long enough for --at 60 --at 120
            cmd = f"{PHIREMAN} fly wildfire --duration-s 130 --speedup 60 --no-wait --out out"
        else:
            cmd = f"{PHIREMAN} sim --mission wildfire --out out/run"
        res = run(cmd, cwd=d, timeout=300)
        assert res.returncode == 0, f"fixture {name}: {cmd}\n{res.stderr[-3000:]}"
        return sorted(p for p in (d / "out").iterdir() if p.is_dir())[-1]


def execute(cmd: str, case: Case, fixtures: Fixtures, base: Path) -> Ctx:
    """Run one documented command per its case; returns the context (raises on a failed check)."""
    cwd = Path(tempfile.mkdtemp(prefix="doc-", dir=base))
    (cwd / "tmp").mkdir()
    line = rewritten(cmd, case)
    ctx = Ctx(cwd=cwd, cmd=line)
    if case.kind == "help":
        words = [w for w in cmd.split()[1:] if re.fullmatch(r"[a-z]+", w)]
        res = run([PHIREMAN, *words, "--help"], cwd, timeout=60)
        ctx.rc, ctx.out, ctx.err = res.returncode, res.stdout, res.stderr
        ctx.expect(res.returncode == 0, "--help failed")
        for flag in _flags(cmd):
            ctx.expect(re.search(rf"{flag}\b", res.stdout), f"{flag} not in the help")
        return ctx
    if case.kind == "bench":
        args = case.help_args or (re.search(r"(bench/\S+\.py)", cmd).group(1),)  # type: ignore[union-attr]  # noqa: E501
        res = run([str(VENV_BIN / "python"), *args, "--help"], ROOT, timeout=120)
        ctx.rc, ctx.out, ctx.err = res.returncode, res.stdout, res.stderr
        ctx.expect(res.returncode == 0, f"{args[0]} --help failed")
        for flag in _flags(cmd):
            ctx.expect(flag in res.stdout, f"{flag} is not an option of {args[0]}")
        return ctx
    for name, dest in case.fixture:
        shutil.copytree(fixtures.get(name), cwd / dest)
    for pre in case.pre:
        if pre == "tile":  # a one-tile XYZ folder at ~/tiles/paradise
            tile = cwd / _HOME_TILE
            tile.parent.mkdir(parents=True)
            tile.write_bytes(Path(ROOT / "docs/images/live_wildfire.png").read_bytes())
            continue
        res = run(pre, cwd, timeout=case.timeout, home=cwd)
        assert res.returncode == 0, f"pre-step {pre!r} failed:\n{res.stderr[-2000:]}"
    if case.kind == "serve":
        if "--forward" in cmd:
            ctx.extra["ports"] = [int(p) for p in re.findall(r"--forward \w+:[\d.]+:(\d+)", line)]
        with Served(line, cwd, home=cwd) as s:
            ctx.served = s
            try:
                assert case.check is not None
                case.check(ctx)
            finally:
                ctx.rc = s.stop()
                ctx.out, ctx.err = "".join(s.out), "".join(s.err)
        ctx.expect(ctx.rc in (0, 130), "did not stop cleanly on Ctrl-C")
        after = ctx.extra.get("after")
        if after:
            after()
        return ctx
    res = run(line, cwd, timeout=case.timeout, home=cwd)
    ctx.rc, ctx.out, ctx.err = res.returncode, res.stdout, res.stderr
    ctx.expect(res.returncode == 0, "exit status")
    if case.check is not None:
        case.check(ctx)
    return ctx


DOCUMENTED = collect()

# Longest first, so that the pool ends together.
_ORDER = {"serve": 0, "run": 1, "help": 2, "bench": 2, "skip": 3}


def _param(cmd: str) -> object:
    case = TABLE.get(cmd)
    marks: list[pytest.MarkDecorator] = []
    if case is not None and case.kind in ("run", "serve"):
        marks.append(pytest.mark.slow)
        if case.xfail:
            marks.append(pytest.mark.xfail(strict=True, reason=case.xfail))
    short = re.sub(r"\s+", " ", cmd)[:90]
    return pytest.param(cmd, marks=marks, id=short)


RUNNABLE = sorted((c for c in DOCUMENTED if c in TABLE), key=lambda c: (_ORDER[TABLE[c].kind], c))


@pytest.fixture(scope="session")
def doc_runs(request, tmp_path_factory):
    """Every selected documented command, started at once on a small pool (the machine's cores
    are shared); each test then waits for its own."""
    base = tmp_path_factory.mktemp("docs")
    fixtures = Fixtures(base)
    selected = [
        item.callspec.params["cmd"]
        for item in request.session.items
        if getattr(item, "originalname", None) == "test_documented_command"
    ]
    pool = ThreadPoolExecutor(3)
    futures = {
        c: pool.submit(execute, c, TABLE[c], fixtures, base)
        for c in sorted(set(selected), key=lambda c: (_ORDER[TABLE[c].kind], c))
        if c in TABLE and TABLE[c].kind != "skip"
    }
    yield futures
    pool.shutdown(wait=True, cancel_futures=True)
    fixtures.pool.shutdown(wait=True)


def test_every_documented_command_is_classified() -> None:
    unknown = sorted(c for c in DOCUMENTED if c not in TABLE)
    stale = sorted(c for c in TABLE if c not in DOCUMENTED)
    assert not unknown, (
        "documented commands in no table (add a run case or a skip reason):\n" + "\n".join(unknown)
    )  # noqa: E501
    assert not stale, "table entries no longer documented (remove them):\n" + "\n".join(stale)
    for cmd, case in TABLE.items():
        if case.kind in ("run", "serve"):
            rewritten(cmd, case)  # every rewrite applies and keeps every documented flag


def test_documentation_was_found() -> None:
    """The collector itself: the README's quick tour and every --help with examples are seen."""
    sources = {s for where in DOCUMENTED.values() for s in where}
    for page in ("README.md", "docs/live_view.md"):
        assert page in sources
    for words in ("fly", "sim", "sweep", "report", "tune", "emulate", "replay", "sitl", "mission"):
        assert f"phireman {words} --help" in sources, words


@pytest.mark.parametrize("cmd", [_param(c) for c in RUNNABLE])
def test_documented_command(cmd: str, doc_runs) -> None:
    case = TABLE[cmd]
    if case.kind == "skip":
        pytest.skip(f"{case.xfail} [{', '.join(sorted(set(DOCUMENTED[cmd])))}]")
    doc_runs[cmd].result()  # re-raises the failed check with the command and its output


def _summary() -> str:  # pragma: no cover - a reviewer's aid: python tests/test_documentation.py
    lines = []
    by_source: dict[str, int] = {}
    for where in DOCUMENTED.values():
        for s in set(where):
            by_source[s] = by_source.get(s, 0) + 1
    for s, n in sorted(by_source.items()):
        lines.append(f"{n:4d}  {s}")
    kinds: dict[str, int] = {}
    for cmd in DOCUMENTED:
        k = TABLE[cmd].kind if cmd in TABLE else "UNCLASSIFIED"
        if k == "run" and TABLE[cmd].xfail:
            k = "xfail"
        kinds[k] = kinds.get(k, 0) + 1
    lines.append(f"{len(DOCUMENTED)} distinct commands: {kinds}")
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    print(_summary())
