"""``python -m resti_lib.synth OUT_DIR [--seed N] [--scale N]``: write the mini-world."""

from __future__ import annotations

import argparse
import json
import sys

from . import generate


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit code."""
    ap = argparse.ArgumentParser(
        prog="python -m resti_lib.synth",
        description="Write the mini-world (sources + legacy benchmark + manifest).",
    )
    ap.add_argument("out_dir", help="output folder")
    ap.add_argument("--seed", type=int, default=0, help="world seed (default 0)")
    ap.add_argument(
        "--scale",
        type=int,
        default=None,
        help="mirror the full 2,064-row legacy structure N times (default: small world)",
    )
    ap.add_argument(
        "--omni6d-camera-convention",
        default="identity",
        choices=["identity", "world_from_camera", "camera_from_world"],
        help="camera pose written in ROPE meta files: identity (the real way) or a SOPE-style pose",
    )
    args = ap.parse_args(argv)
    summary = generate(
        args.out_dir, seed=args.seed, scale=args.scale, omni6d_camera_convention=args.omni6d_camera_convention
    )
    json.dump(
        {k: summary[k] for k in ("out_dir", "seed", "scale", "files", "bytes", "seconds")}
        | {"rows": summary["counts"]["rows"]},
        sys.stdout,
        indent=1,
    )
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
