#!/usr/bin/env python
"""Reproduce the seed paper's synthetic Tables I and II (thin wrapper over plsgraph.sim.paper.reproduce_paper)."""

from __future__ import annotations

import argparse
import sys

from plsgraph.errors import PlsgraphError
from plsgraph.sim.paper import Protocol, pls_variant_study, reproduce_paper


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", required=True, help="output directory for paper_tables.md and paper_tables.json")
    ap.add_argument("--trials", type=int, default=200, help="trials per route (default 200, as in the paper)")
    ap.add_argument("--quick", action="store_true", help="20 trials, no sensitivity study (a few seconds)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--force", action="store_true", help="overwrite existing output files")
    ap.add_argument("--no-study", action="store_true", help="skip the sensitivity and centring study")
    d = Protocol()
    ap.add_argument("--scale", type=float, default=d.scale, help=f"route size, m or m/s (default {d.scale:g})")
    ap.add_argument("--quantity", choices=("position", "velocity"), default=d.quantity)
    ap.add_argument("--noise-model", choices=("independent", "paper"), default=d.noise_model)
    ap.add_argument("--planar-side", choices=("camera", "base"), default=d.planar_side)
    ap.add_argument("--pls-variants", action="store_true", help="only print the PLS design-choice study and exit")
    args = ap.parse_args(argv)
    protocol = Protocol(
        scale=args.scale, quantity=args.quantity, noise_model=args.noise_model, planar_side=args.planar_side
    )
    if args.pls_variants:
        print(pls_variant_study(args.trials, args.seed, protocol))
        return 0

    def progress(done: int, total: int) -> None:
        print(f"\r{done}/{total} routes", end="" if done < total else "\n", file=sys.stderr, flush=True)

    try:
        res = reproduce_paper(
            args.out,
            trials=args.trials,
            quick=args.quick,
            seed=args.seed,
            overwrite=args.force,
            progress=progress,
            study=False if args.no_study else None,
            protocol=protocol,
        )
    except PlsgraphError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(res["markdown"])
    print(f"wrote {res['paths']['markdown']} and {res['paths']['json']}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
