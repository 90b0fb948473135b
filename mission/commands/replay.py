"""phireman replay RUN_DIR: plots and an animation of a recorded run."""

from __future__ import annotations

import argparse
import pathlib
import sys

HELP = "render a recorded run: Fig. 2 time series, Fig. 4 frame strip, animation"
DESCRIPTION = """\
Read a run directory written by 'phireman sim --mission ... --out DIR' or 'phireman fly' and render
(RUN_DIR may also be a parent of run directories, e.g. fly's output dir: the newest is replayed):

  fig2_timeseries.png  drones alive, drones alive and active, tasks connected over time
  frames.png           five snapshots with a full legend: base and its radio range, radio links,
                       drones by state, crews by name with the drone serving each, the task tree
                       (rebuilt from the positions when the run did not record it), hazard zones
  animation.gif        the whole run with axes, legend and clock, about 10 s long (--animation mp4
                       when ffmpeg is installed, none to skip)
  link_profiles.png    a terrain run (radio.model: terrain): the profiles of two links, one the
                       terrain blocks and one that closes; the maps above are drawn over the
                       shaded relief with contours (docs/terrain.md)

--serve shows a 'phireman fly' run, or an in-process run of 'phireman sim --mission', on the
live page; --export needs a 'phireman fly' run.

examples:
  phireman sim --mission wildfire --out runs/wildfire && phireman replay runs/wildfire
  phireman replay runs/wildfire --out /tmp/plots --animation none
  phireman replay runs                  # the newest run directory under runs/
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mission.commands.options import positive_int

    p.add_argument(
        "run_dir",
        type=pathlib.Path,
        help="a run directory (holds truth.npz), or a directory of run directories (the newest is used)",
    )
    p.add_argument(
        "--out", type=pathlib.Path, default=None, help="where to write (default: the run directory)"
    )
    p.add_argument(
        "--animation",
        choices=["gif", "mp4", "none"],
        default="gif",
        help="animation format (default gif)",
    )
    p.add_argument(
        "--max-frames", type=positive_int, default=100, help="animation frames (default 100)"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    from mission.commands.live_view import add_replay_arguments

    add_replay_arguments(p)  # --serve, --tiles, --export, --at


def run(args) -> int:
    from mission.commands.options import UserError, writable_dir
    from mission.view.replay import check_animation_writer, find_run_dir, replay

    try:
        check_animation_writer(args.animation)
        run_dir, note = find_run_dir(args.run_dir)
    except (FileNotFoundError, ValueError) as exc:
        raise UserError(str(exc)) from None
    if note:
        print(note, file=sys.stderr)
    from mission.commands.live_view import run_replay

    served = run_replay(args, run_dir)  # --serve / --export: the live page or a GIS file, no plots
    if served is not None:
        return served
    # The pictures: their directory checked before any drawing.
    if args.out is not None:
        writable_dir(args.out)
    else:
        writable_dir(run_dir, "the run directory (give --out DIR to write elsewhere)")
    from tqdm import tqdm

    bar = None
    if args.animation != "none" and not args.no_progress:
        bar = tqdm(
            total=args.max_frames, unit="frame", file=sys.stderr, leave=False, desc="animation"
        )
    try:
        files = replay(
            run_dir, args.out, args.animation, args.max_frames, progress=bar.update if bar else None
        )
    except (FileNotFoundError, ValueError) as exc:
        raise UserError(str(exc)) from None
    finally:
        if bar:
            bar.close()
    for f in files:
        print(f"wrote {f}")
    return 0
