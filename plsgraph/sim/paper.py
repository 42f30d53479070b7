"""Reproduce the synthetic Tables I and II of the seed paper (PLS-Calib) next to its published numbers.

``reproduce_paper`` runs the protocol of ``plsgraph.sim.routes`` for every route and method, writes
``paper_tables.md`` and ``paper_tables.json`` into a directory and returns the figures (and the markdown).
Methods: the paper's two columns, "cca" (centred CCA as prior motion-correlation work does it) and "pls" (the paper's
Eqs. 11-21 verbatim, scored on its raw, not quite orthonormal Eq. 20 matrix with the paper's e_R formula), plus two
extra columns, "procrustes" and "pls_default" (this library's repaired PLS).

Unless ``quick``, a sensitivity study measures what the paper leaves open (positions or velocities, the noise
model, which side carries the zero axis, the route scale) and what centring does to motion with a non-zero mean.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from ..calib.solvers import solve
from ..core.geometry import rotation_error_deg
from ..errors import InputError, PlsgraphError
from .routes import PLANAR_ROUTES, ROUTE_TITLES, make_trials

log = logging.getLogger(__name__)

#: Most trials per cell reproduce_paper takes: 50 times the paper's 200 (time and memory grow with them).
MAX_TRIALS = 10_000

#: Published figures (degrees). Table I gives means only; Table II mean, std and the reduction in percent.
PAPER_TABLE1 = {"6dof": {"cca": 0.16, "pls": 0.21}, "planar": {"cca": 26.56, "pls": 0.26}}
PAPER_TABLE2 = {
    "circle": {"cca": (48.94, 0.10), "pls": (0.23, 0.10), "reduction_pct": 99.53},
    "v_shape": {"cca": (16.10, 0.20), "pls": (0.48, 0.18), "reduction_pct": 97.02},
    "z_shape": {"cca": (49.95, 0.17), "pls": (0.57, 0.23), "reduction_pct": 98.86},
    "s_shape": {"cca": (20.33, 0.06), "pls": (1.05, 0.47), "reduction_pct": 94.83},
}

#: method key -> (column title, solve() keyword arguments, score the raw matrix instead of R_base_cam)
METHODS: dict[str, tuple[str, dict, bool]] = {
    "cca": ("CCA", {"method": "cca", "center": True}, False),
    "pls": ("PLS (paper-exact)", {"method": "pls", "paper": True}, True),
    "procrustes": ("Procrustes", {"method": "procrustes"}, False),
    "pls_default": ("PLS (default)", {"method": "pls"}, False),
}

ProgressFn = Callable[[int, int], None]


@dataclass(frozen=True)
class Protocol:
    """Choices behind the tables; the paper fixes n_samples and sigma, the rest is ours (see docs/paper_tables.md)."""

    n_samples: int = 100
    sigma: float = 0.10
    scale: float = 1.0
    quantity: str = "position"
    noise_model: str = "independent"
    planar_side: str = "camera"
    exact_zero_axis: bool = False


def route_errors(
    route: str, methods: dict[str, tuple[str, dict, bool]], trials: int, seed: int, protocol: Protocol
) -> dict[str, np.ndarray]:
    """Rotation error (deg) of every method on every trial of ``route``; NaN where a method refused the data."""
    ts = make_trials(
        route,
        count=trials,
        seed=seed,
        n=protocol.n_samples,
        sigma=protocol.sigma,
        scale=protocol.scale,
        quantity=protocol.quantity,
        noise_model=protocol.noise_model,
        planar_side=protocol.planar_side,
        exact_zero_axis=protocol.exact_zero_axis,
    )
    out = {}
    for key, (_, kwargs, use_raw) in methods.items():
        errs = np.full(ts.count, np.nan)
        for i in range(ts.count):
            try:
                res = solve(ts.X[i], ts.Y[i], **kwargs)
            except PlsgraphError as exc:  # a refusal is a result too: counted as a failure, not hidden
                log.debug("%s refused trial %d of %s: %s", key, i, route, exc)
                continue
            errs[i] = rotation_error_deg(res.R_raw if use_raw else res.R_base_cam, ts.R_gt[i])
        out[key] = errs
    return out


def summarize(errors: np.ndarray) -> dict:
    """Mean and (population) std over the trials a method solved, with the count of trials and of refusals."""
    ok = errors[np.isfinite(errors)]
    return {
        "mean_deg": float(ok.mean()) if ok.size else float("nan"),
        "std_deg": float(ok.std()) if ok.size else float("nan"),
        "n_trials": int(ok.size),
        "n_failed": int(errors.size - ok.size),
    }


def run_tables(trials: int, seed: int, protocol: Protocol, progress: ProgressFn | None = None) -> dict:
    """Tables I and II as nested dicts: table -> route -> method -> summary."""
    t1_routes, t2_routes = ("6dof", "planar"), PLANAR_ROUTES
    total, done = len(t1_routes) + len(t2_routes), 0
    tables: dict[str, dict] = {"table1": {}, "table2": {}}
    for table, routes in (("table1", t1_routes), ("table2", t2_routes)):
        for route in routes:
            errs = route_errors(route, METHODS, trials, seed, protocol)
            tables[table][route] = {k: summarize(e) for k, e in errs.items()}
            done += 1
            if progress is not None:
                progress(done, total)
    for res in tables["table2"].values():
        c, p = res["cca"]["mean_deg"], res["pls"]["mean_deg"]
        res["reduction_pct"] = float(100.0 * (1.0 - p / c)) if c > 0 else float("nan")
    return tables


def sensitivity_study(trials: int, seed: int, base: Protocol) -> list[dict]:
    """Mean error over the four planar routes for each variant of the protocol (one row per variant)."""
    variants: list[tuple[str, Protocol]] = []
    for quantity in ("position", "velocity"):
        for noise_model in ("independent", "paper"):
            for side in ("camera", "base"):
                p = replace(base, quantity=quantity, noise_model=noise_model, planar_side=side)
                variants.append((f"{quantity}, {noise_model} noise, zero axis on {side}", p))
    if base.noise_model == "independent":
        p = replace(base, planar_side="base", exact_zero_axis=True)
        variants.append((f"{base.quantity}, independent noise, zero axis on base and noise-free (odometry)", p))
    for scale in (0.5, 2.0, 5.0):
        variants.append((f"{base.quantity}, {base.noise_model} noise, scale {scale:g}", replace(base, scale=scale)))
    rows = []
    for label, prot in variants:
        per_route = {r: route_errors(r, METHODS, trials, seed, prot) for r in PLANAR_ROUTES}
        row: dict = {"variant": label, "protocol": asdict(prot), "methods": {}}
        for key in METHODS:
            stats = [summarize(per_route[r][key]) for r in PLANAR_ROUTES]
            means = [st["mean_deg"] for st in stats if st["n_trials"] > 0]
            row["methods"][key] = {
                "mean_deg": float(np.mean(means)) if means else float("nan"),
                "worst_route_deg": float(np.max(means)) if means else float("nan"),
                "n_failed": int(sum(st["n_failed"] for st in stats)),
                "routes_refused": [r for r, st in zip(PLANAR_ROUTES, stats, strict=True) if st["n_trials"] == 0],
            }
        rows.append(row)
    return rows


CENTERING_METHODS: dict[str, tuple[str, dict, bool]] = {
    "pls_default": ("PLS default, raw", {"method": "pls"}, False),
    "pls_default_centred": ("PLS default, centred", {"method": "pls", "center": True}, False),
    "pls_paper_uncentred": ("PLS paper, raw", {"method": "pls", "paper": True, "center": False}, True),
    "pls_paper": ("PLS paper, centred", {"method": "pls", "paper": True}, True),
    "cca_uncentred": ("CCA, raw", {"method": "cca", "center": False}, False),
    "cca": ("CCA, centred", {"method": "cca", "center": True}, False),
    "procrustes": ("Procrustes, raw", {"method": "procrustes"}, False),
    "procrustes_centred": ("Procrustes, centred", {"method": "procrustes", "center": True}, False),
}


def centering_study(trials: int, seed: int, base: Protocol) -> dict:
    """Velocity samples (non-zero mean on every route but the circle): each method with and without centring."""
    prot = replace(base, quantity="velocity")
    out = {}
    for route in PLANAR_ROUTES + ("6dof",):
        errs = route_errors(route, CENTERING_METHODS, trials, seed, prot)
        out[route] = {k: summarize(e) for k, e in errs.items()}
    return out


def _fmt(s: dict, std: bool = True) -> str:
    if s["n_trials"] == 0:
        return f"refused ({s['n_failed']})"
    txt = f"{s['mean_deg']:.2f} ± {s['std_deg']:.2f}" if std else f"{s['mean_deg']:.2f}"
    return txt + (f" ({s['n_failed']} refused)" if s["n_failed"] else "")


def _pct(v: float) -> str:
    return f"{v:.2f}" if np.isfinite(v) else "n/a"


def render_markdown(result: dict) -> str:
    """The tables as markdown, the paper's figures next to ours."""
    prot = result["protocol"]
    n = result["trials"]
    lines = [
        "# PLS-Calib synthetic tables, reproduced",
        "",
        f"Protocol: {n} trials per route, {prot['n_samples']} samples each, sigma = {prot['sigma']} on X and Y, "
        f"R_gt from ZYX Euler angles uniform in [-90, 90] deg, seed {result['seed']}; X holds "
        f"{prot['quantity']}s, route scale {prot['scale']:g}, noise model '{prot['noise_model']}', zero axis on "
        f"the {prot['planar_side']} side. Errors are geodesic e_R in degrees, mean ± std (population).",
        "",
        "## Table I: full 6-DoF vs ground-constrained motion",
        "",
        "| Motion | CCA (paper) | CCA (ours) | PLS (paper) | PLS paper-exact (ours) | Procrustes | PLS default |",
        "|---|---|---|---|---|---|---|",
    ]
    for route, res in result["table1"].items():
        pub = PAPER_TABLE1[route]
        lines.append(
            f"| {ROUTE_TITLES[route]} | {pub['cca']:.2f} | {_fmt(res['cca'])} | {pub['pls']:.2f} | "
            f"{_fmt(res['pls'])} | {_fmt(res['procrustes'])} | {_fmt(res['pls_default'])} |"
        )
    lines += [
        "",
        "## Table II: planar routes",
        "",
        "| Route | CCA (paper) | CCA (ours) | PLS (paper) | PLS paper-exact (ours) | Reduction % (paper) "
        "| Reduction % (ours) | Procrustes | PLS default |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for route, res in result["table2"].items():
        pub = PAPER_TABLE2[route]
        lines.append(
            f"| {ROUTE_TITLES[route]} | {pub['cca'][0]:.2f} ± {pub['cca'][1]:.2f} | {_fmt(res['cca'])} | "
            f"{pub['pls'][0]:.2f} ± {pub['pls'][1]:.2f} | {_fmt(res['pls'])} | {pub['reduction_pct']:.2f} | "
            f"{_pct(res['reduction_pct'])} | {_fmt(res['procrustes'])} | {_fmt(res['pls_default'])} |"
        )
    if "sensitivity" in result:
        keys = list(METHODS)
        lines += [
            "",
            "## Sensitivity: what the paper does not specify",
            "",
            "Mean of the per-route mean errors over the four planar routes (worst route in brackets), over the "
            "routes where the method returned a result; refused trials are counted, not scored.",
            "",
            "| Variant | " + " | ".join(METHODS[k][0] for k in keys) + " |",
            "|---|" + "---|" * len(keys),
        ]
        for row in result["sensitivity"]:
            cells = []
            for k in keys:
                m = row["methods"][k]
                txt = (
                    "refused" if not np.isfinite(m["mean_deg"]) else f"{m['mean_deg']:.2f} [{m['worst_route_deg']:.2f}]"
                )
                if m["routes_refused"] and np.isfinite(m["mean_deg"]):
                    txt += " (refused on " + ", ".join(ROUTE_TITLES[r] for r in m["routes_refused"]) + ")"
                elif m["n_failed"] and np.isfinite(m["mean_deg"]):
                    txt += f" ({m['n_failed']} refused)"
                cells.append(txt)
            lines.append(f"| {row['variant']} | " + " | ".join(cells) + " |")
    if "centering" in result:
        keys = list(CENTERING_METHODS)
        lines += [
            "",
            "## Centring on motion with a non-zero mean (velocity samples)",
            "",
            "| Route | " + " | ".join(CENTERING_METHODS[k][0] for k in keys) + " |",
            "|---|" + "---|" * len(keys),
        ]
        for route, res in result["centering"].items():
            lines.append(f"| {ROUTE_TITLES[route]} | " + " | ".join(_fmt(res[k], std=False) for k in keys) + " |")
    return "\n".join(lines) + "\n"


def _json_safe(obj):
    """NaN (a method refused every trial) becomes null, so the file is strict JSON."""
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    return obj


PLS_VARIANTS: dict[str, tuple[str, dict, bool]] = {
    "auto_fitted": ("K auto, fitted (default)", {"method": "pls"}, False),
    "k2_fitted": ("K=2, fitted", {"method": "pls", "n_components": 2}, False),
    "k3_fitted": ("K=3, fitted", {"method": "pls", "n_components": 3}, False),
    "auto_polar": ("K auto, polar", {"method": "pls", "rotation": "polar"}, False),
    "k2_polar": ("K=2, polar", {"method": "pls", "rotation": "polar", "n_components": 2}, False),
    "auto_rows": ("K auto, rows (Eq. 20)", {"method": "pls", "rotation": "rows"}, True),
    "auto_column": ("K auto, column scaling", {"method": "pls", "scale": "column"}, False),
    "paper": ("paper-exact", {"method": "pls", "paper": True}, True),
    "paper_projected": ("paper-exact, scored on its nearest rotation", {"method": "pls", "paper": True}, False),
    "procrustes": ("Procrustes", {"method": "procrustes"}, False),
}


def pls_variant_study(trials: int, seed: int, base: Protocol | None = None) -> str:
    """Markdown table: PLS design choices (components K, rotation construction, scaling) under protocol variants.

    Rows: the four planar routes (mean of per-route means) and the 6-DoF route, for each combination of noise model
    and zero-axis side. This is the measurement behind the defaults of ``closedform.solve(method="pls")``.
    """
    base = base or Protocol()
    keys = list(PLS_VARIANTS)
    lines = [
        "| Data | " + " | ".join(PLS_VARIANTS[k][0] for k in keys) + " |",
        "|---|" + "---|" * len(keys),
    ]
    for noise_model in ("independent", "paper"):
        for side in ("camera", "base"):
            prot = replace(base, noise_model=noise_model, planar_side=side)
            errs = {r: route_errors(r, PLS_VARIANTS, trials, seed, prot) for r in PLANAR_ROUTES + ("6dof",)}
            for label, routes in (("planar routes", PLANAR_ROUTES), ("6-DoF", ("6dof",))):
                if label == "6-DoF" and side == "base":
                    continue  # the 6-DoF route has no zero axis, the side makes no difference
                cells = []
                for k in keys:
                    st = [summarize(errs[r][k]) for r in routes]
                    ok = [x["mean_deg"] for x in st if x["n_trials"]]
                    fails = sum(x["n_failed"] for x in st)
                    cells.append((f"{np.mean(ok):.2f}" if ok else "refused") + (f" ({fails} refused)" if fails else ""))
                where = f", zero axis on {side}" if label != "6-DoF" else ""
                lines.append(f"| {label}, {noise_model} noise{where} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def reproduce_paper(
    out_dir: str | Path,
    trials: int = 200,
    quick: bool = False,
    seed: int = 0,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
    study: bool | None = None,
    protocol: Protocol | None = None,
) -> dict:
    """Run the synthetic protocol, write ``out_dir/paper_tables.md`` and ``.json``, return the figures.

    ``quick`` uses at most 20 trials and skips the sensitivity study (a few seconds); ``study`` forces it on or off.
    Existing output files raise InputError unless ``overwrite``. ``progress(done, total)`` is called after each
    route. The returned dict has "table1", "table2" (route -> method -> mean_deg, std_deg, n_trials, n_failed),
    "paper" (published figures), "protocol", "markdown" and "paths".
    """
    if isinstance(trials, bool) or not isinstance(trials, int | np.integer) or not 2 <= trials <= MAX_TRIALS:
        raise InputError(f"trials (--trials) must be a whole number from 2 (to report a std) to {MAX_TRIALS} (50 times "
                         f"the paper's 200; memory and time grow with it), got {trials!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"seed (--seed) must be a whole number >= 0, got {seed!r}")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"output path {out} exists and is not a folder; choose another --out")
    md_path, json_path = out / "paper_tables.md", out / "paper_tables.json"
    existing = [p for p in (md_path, json_path) if p.exists()]
    if existing and not overwrite:
        raise InputError(
            f"{', '.join(str(p) for p in existing)} already exist; pass --force (overwrite=True) to replace them or "
            "choose another --out"
        )
    protocol = protocol or Protocol()
    n = min(int(trials), 20) if quick else int(trials)
    run_study = (not quick) if study is None else bool(study)
    result: dict = {"trials": n, "seed": int(seed), "protocol": asdict(protocol)}
    result.update(run_tables(n, seed, protocol, progress))
    if run_study:
        log.info("sensitivity study (%d trials per variant and route)", n)
        result["sensitivity"] = sensitivity_study(n, seed, protocol)
        result["centering"] = centering_study(n, seed, protocol)
    result["paper"] = {
        "table1": PAPER_TABLE1,
        "table2": {
            r: {"cca": list(v["cca"]), "pls": list(v["pls"]), "reduction_pct": v["reduction_pct"]}
            for r, v in PAPER_TABLE2.items()
        },
    }
    markdown = render_markdown(result)
    out.mkdir(parents=True, exist_ok=True)
    md_path.write_text(markdown)
    json_path.write_text(json.dumps(_json_safe(result), indent=2, allow_nan=False) + "\n")
    result["markdown"] = markdown
    result["paths"] = {"markdown": str(md_path), "json": str(json_path)}
    return result
