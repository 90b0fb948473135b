"""phireman replay RUN_DIR: plots and an animation of a recorded run."""
from __future__ import annotations

import argparse
import pathlib
import sys

HELP = "render a recorded run: Fig. 2 time series, Fig. 4 frame strip, animation"
DESCRIPTION = """\
Read a run directory written by 'phireman sim --mission ... --out DIR' or 'phireman fly' and render:

  fig2_timeseries.png  drones alive, drones alive and active, tasks connected over time
  frames.png           five snapshots: radio links, drones by state, tasks, task tree, hazard zones
  animation.gif        the whole run (or --animation mp4 when ffmpeg is installed, none to skip)

examples:
  phireman sim --mission wildfire --out runs/wildfire && phireman replay runs/wildfire
  phireman replay runs/wildfire --out /tmp/plots --animation none
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", type=pathlib.Path, help="a run directory (holds truth.npz)")
    p.add_argument("--out", type=pathlib.Path, default=None, help="where to write (default: the run directory)")
    p.add_argument("--animation", choices=["gif", "mp4", "none"], default="gif", help="animation format (default gif)")
    p.add_argument("--max-frames", type=int, default=120, help="animation frames (default 120)")
    from mission.live.cli import add_replay_arguments

    add_replay_arguments(p)  # --serve, --tiles, --export, --at


def run(args) -> int:
    from mission.cli import UserError
    from mission.replay import replay

    if not args.run_dir.is_dir():
        raise UserError(f"{args.run_dir}: not a directory")
    from mission.live.cli import run_replay

    served = run_replay(args)  # --serve / --export: the live page or a GIS file instead of plots
    if served is not None:
        return served
    from tqdm import tqdm

    bar = tqdm(total=args.max_frames, unit="frame", file=sys.stderr, leave=False) if args.animation != "none" else None
    try:
        files = replay(args.run_dir, args.out, args.animation, args.max_frames, progress=bar.update if bar else None)
    except (FileNotFoundError, ValueError) as exc:
        raise UserError(str(exc)) from None
    finally:
        if bar:
            bar.close()
    for f in files:
        print(f"wrote {f}")
    return 0
