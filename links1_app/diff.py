"""``links1 diff A B``: compare a test image with a reference under a metric and threshold.

The command line over the core's image metrics (:mod:`links1.imaging.diff`: rmse, relmse,
mae, max, psnr, flip; heatmaps). ``links1 diff`` comes from :func:`add_cli`;
``python -m links1_app.diff A B [options]`` runs it stand-alone.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Sequence

from links1.errors import Links1Error, UsageError
from links1.imaging.diff import ERROR_MAPS, HIGHER_IS_BETTER, METRICS, all_metrics, exceeds, heatmap
from links1.imaging.image import read_image

DESCRIPTION = ("Compare a test image A with a reference image B (EXR or PNG): print rmse, "
               "relmse, mae, max, psnr and flip; exit 1 when --metric exceeds --threshold "
               "(falls below it for psnr), 2 on bad input.")


def _configure(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    p.add_argument("a", metavar="A", help="test image (.exr or .png)")
    p.add_argument("b", metavar="B", help="reference image (.exr or .png)")
    p.add_argument("--metric", choices=METRICS, default="relmse",
                   help="metric tested against --threshold (default: relmse)")
    p.add_argument("--threshold", type=float, default=None,
                   help="fail (exit 1) when the metric is above this (below, for psnr)")
    p.add_argument("--heatmap", metavar="OUT.png", default=None,
                   help="write a false-colour per-pixel error image")
    p.add_argument("--heatmap-error", choices=ERROR_MAPS, default="abs",
                   help="per-pixel error shown in the heatmap (default: abs)")
    p.add_argument("--no-flip", action="store_true", help="skip the (slower) FLIP metric "
                   "unless it is the --metric")
    p.add_argument("--json", action="store_true", help="print a JSON object instead of a table")
    p.set_defaults(func=run_cli)
    return p


def add_cli(subparsers) -> argparse.ArgumentParser:
    """Add the ``diff`` subcommand to an argparse ``subparsers`` object; returns its parser.

    The parser's defaults include ``func=run_cli`` so a dispatcher can call
    ``args.func(args)``.
    """
    p = subparsers.add_parser("diff", help="compare two images (metrics, threshold, heatmap)",
                              description=DESCRIPTION)
    return _configure(p)


def _fmt(v: float) -> str:
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return f"{v:.6g}"


def _json_value(v):
    """JSON has no inf/nan: write them as the strings 'inf', '-inf', 'nan'."""
    return v if math.isfinite(v) else _fmt(v)


def run_cli(args: argparse.Namespace) -> int:
    """Run ``links1 diff`` with parsed ``args``; returns the exit status (0, 1 or 2).

    Bad input (missing/unreadable files, size or channel mismatch, missing flip package)
    prints one line ``links1 diff: error: ...`` to stderr and returns 2.
    """
    try:
        if args.threshold is not None and math.isnan(args.threshold):
            raise UsageError("--threshold must be a number, got nan")
        a = read_image(args.a)
        b = read_image(args.b)
        names = [m for m in METRICS if not (m == "flip" and args.no_flip and args.metric != "flip")]
        try:
            import flip_evaluator  # noqa: F401, PLC0415  (lazy: whether the optional FLIP package is there)
            have_flip = True
        except ImportError:
            have_flip = False
        if not have_flip and args.metric != "flip":
            names = [m for m in names if m != "flip"]
        values = all_metrics(a, b, labels=(args.a, args.b),
                             ldr=(Path(args.a).suffix.lower() == ".png"
                                  and Path(args.b).suffix.lower() == ".png"),
                             metrics=names)
        if args.heatmap:
            heatmap(a, b, args.heatmap, error=args.heatmap_error,
                    title=f"{Path(args.a).name} vs {Path(args.b).name}")
    except Links1Error as e:
        print(f"links1 diff: error: {e}", file=sys.stderr)
        return 2

    value = values[args.metric]
    failed = args.threshold is not None and exceeds(args.metric, value, args.threshold)
    h, w = a.shape[:2]
    channels = a.shape[2] if a.ndim == 3 else 1
    if args.json:
        out = {"a": str(args.a), "b": str(args.b), "width": w, "height": h,
               "channels": channels, "metrics": {k: _json_value(v) for k, v in values.items()},
               "metric": args.metric, "value": _json_value(value),
               "threshold": args.threshold, "passed": not failed,
               "heatmap": str(args.heatmap) if args.heatmap else None}
        print(json.dumps(out, indent=2))
    else:
        print(f"{args.a} vs {args.b} ({w}x{h}, {channels} channels)")
        for k, v in values.items():
            mark = "  <-" if k == args.metric else ""
            print(f"  {k:<7} {_fmt(v):>14}{mark}")
        if args.threshold is not None:
            rel = "<" if args.metric in HIGHER_IS_BETTER else ">"
            verdict = "FAIL" if failed else "ok"
            print(f"{verdict}: {args.metric} = {_fmt(value)} (fails if {rel} {args.threshold:g})")
        if args.heatmap:
            print(f"heatmap: {args.heatmap}")
    return 1 if failed else 0


def main(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry point: ``python -m links1_app.diff A B [options]``."""
    parser = _configure(argparse.ArgumentParser(prog="links1 diff", description=DESCRIPTION))
    return run_cli(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
