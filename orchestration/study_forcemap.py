"""The impedance loop's stability against the target stiffness and the wall's (impedance paper).

``flexfusion study force-map --out DIR [--k-z 1000,2000,5000,10000] [--k-wall 2000,5000,10000,20000]``

The target stiffness ``K_z`` of the impedance relation is our choice, not the paper's: the
paper (García, Robertsson, Gómez Ortega, Johansson, section V) gives its LQR weights and the
cardboard screen's 5 N/mm but no target stiffness. Our contact scenarios use ``K_z`` = 2000 N/m,
with which the paper's controller is unstable on the compliant tool (``flexfusion study
contact``). This study maps the loop over a grid of ``K_z`` and wall stiffnesses ``k_wall``,
with the force observer's estimate and with the raw wrist-sensor reading in the loop, and judges
the paper's claims where the loop is stable.

Each cell is the shipped contact scenario (``contact_observer.toml`` or ``contact_raw.toml``,
the paper's controller structure, the compliant tool, encoder kinematics in the loop, the
calibrated tool mass) with three changes: ``impedance.K_z = K_z``, ``contact.stiffness =
k_wall``, and ``impedance.k_env = k_wall`` (the controller is designed for the wall it touches,
as the paper designed for its known screen). The target damping ``D_z`` stays the scenario's
(350 N s/m), so a larger ``K_z`` is also a less damped target.

Criterion (per cell, :func:`orchestration.study_contact.case_metrics`): **stable** when every
signal is finite, the contact is never lost after the first touch, the observer never flags a
fault, and in the stationary window (0.5 s after the path's last move to the stop time) the
contact force's standard deviation is below 10 % of its mean (a bounded, decaying oscillation).
Reported beside it: the overshoot of the contact force through the transition over the
impedance relation's stationary force, the number of contact losses, and the stationary
force's error against the impedance relation.

The paper's claims, judged on the stable cells only (:func:`map_findings`): the stationary force
follows the impedance relation (within 5 %), and with the observer the transition is not worse
than with the raw reading (overshoot and contact losses not larger, both loops stable).

Output: ``DIR/force_map.json`` (grid, per cell the metrics, the findings, the wall time and the
engine) and ``DIR/force_map.png`` (the map: one panel per force in the loop).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from orchestration import study
from orchestration import study_contact as sc
from orchestration.results import json_safe

#: The default grid [N/m]: around the scenarios' K_z = 2000 and the paper's 5 N/mm wall.
K_Z = (1000.0, 2000.0, 5000.0, 10000.0)
K_WALL = (2000.0, 5000.0, 10000.0, 20000.0)
FEEDBACKS = ("observer", "raw")
#: The paper's claim on the stationary contact is checked against this relative error.
STEADY_F_LIMIT = sc.LIMITS["steady_F_err"]


def cell_key(K_z: float, k_wall: float, feedback: str) -> str:
    """The name of one cell: ``"K_z=2000/k_wall=5000/observer"``."""
    return f"K_z={K_z:g}/k_wall={k_wall:g}/{feedback}"


def cell_overrides(K_z: float, k_wall: float, structure: str = "paper") -> tuple[str, ...]:
    """The overrides of one cell on the shipped contact scenarios (see the module docstring)."""
    return (f"impedance.K_z={K_z!r}", f"contact.stiffness={k_wall!r}", f"impedance.k_env={k_wall!r}",
            f'impedance.structure="{structure}"')


def _check_grid(name: str, values: Sequence[float]) -> None:
    if not values or any(not (v > 0 and np.isfinite(v)) for v in values):
        raise study.StudyError(f"{name} needs positive stiffnesses, got {list(values)}")


def run_map(out_dir: str | Path, K_z: Sequence[float] = K_Z, k_wall: Sequence[float] = K_WALL,
            feedbacks: Sequence[str] = FEEDBACKS, structure: str = "paper", overrides: Sequence[str] = (),
            workers: int | None = None, scheduler: str | None = None, progress: bool = True,
            plots: bool = True, engine: str = "batched", check_cases: int = sc.CHECK_CASES) -> dict[str, Any]:
    """Run every cell and write ``force_map.json`` (and ``force_map.png``) into ``out_dir``.

    Parameters
    ----------
    out_dir
        Output folder (created).
    K_z, k_wall
        The grid: target stiffnesses and wall stiffnesses [N/m].
    feedbacks
        The forces in the loop: ``"observer"`` (the ForceObserver's estimate), ``"raw"`` (the
        wrist sensor's reading with gravity removed).
    structure
        The impedance controller's structure (``"paper"``: eqs. 39-41; ``"integral"``: ours).
    overrides
        Further ``comp.param=value`` for every cell.
    workers, scheduler, progress
        Executor (:func:`orchestration.study.open_executor`) and progress bar.
    plots
        Write the map's figure.
    engine, check_cases
        As :func:`orchestration.study_contact.run_study`: the cells on the batched engine, that
        many of them also through the FMUs (identical to 1e-12 relative), or every cell through
        the FMUs.

    Returns
    -------
    dict
        The content of ``force_map.json``.

    Raises
    ------
    StudyError
        An empty or non-positive grid, an unknown force in the loop, failed runs.
    """
    from orchestration.study import StudyError, check_engine, map_jobs, open_executor, simulate_recorded

    _check_grid("--k-z", K_z)
    _check_grid("--k-wall", k_wall)
    unknown = [f for f in feedbacks if f not in sc.SCENARIO_FILES]
    if unknown or not feedbacks:
        raise StudyError(f"the force in the loop must be one of {', '.join(sc.SCENARIO_FILES)}, got {list(feedbacks)}")
    check_engine(engine, check_cases, "--check-cases")
    every = {cell_key(kz, kw, fb): (fb, tuple(overrides) + cell_overrides(kz, kw, structure))
             for kz in K_z for kw in k_wall for fb in feedbacks}
    poles = {k: design_poles(sc.SCENARIO_FILES[fb], ov) for k, (fb, ov) in every.items()}
    cells = {k: v for k, v in every.items() if np.all(poles[k].real < 0)}
    jobs = [(str(sc.SCENARIO_FILES[fb]), ov, sc.RECORDED) for fb, ov in cells.values()]
    t0 = time.perf_counter()
    results, engine_info = [], {"used": "none: no cell has a stable design"}
    with open_executor(workers=workers or 2, scheduler=scheduler) as ex:
        if not jobs:
            pass
        elif engine == "batched":
            results, engine_info = sc._run_batched(list(cells), jobs, ex, progress, check_cases)
        else:
            results = map_jobs(simulate_recorded, jobs, ex, desc="force map", progress=progress, star=True)
            engine_info = {"used": "fmu"}
    wall = time.perf_counter() - t0
    per_cell: dict[str, Any] = {}
    ran = dict(zip(cells, results))
    for key, (fb, ov) in every.items():
        setup = sc.scenario_setup(sc.SCENARIO_FILES[fb], ov)
        cell: dict[str, Any] = {"K_z": setup.K_z, "k_wall": setup.k_wall, "feedback": fb,
                                "design_poles_max_real": float(np.max(poles[key].real))}
        if key in ran:
            cell.update(design="stable", **sc.case_metrics(sc.series_from_run(ran[key], fb), setup),
                        run_wall_time_s=ran[key]["wall_time"])
        else:       # the controller refuses this design (ImpedanceController.setup): nothing to run
            cell.update(design="unstable", stable=False, overshoot=float("nan"), contact_losses=None)
        per_cell[key] = cell
    data: dict[str, Any] = {
        "study": "force-map", "structure": structure, "K_z": list(K_z), "k_wall": list(k_wall),
        "feedbacks": list(feedbacks), "overrides": list(overrides),
        "design": "impedance.k_env = k_wall (the controller designed for the wall it touches); D_z, the "
                  "tool and its mount, the path and the sensors as in the shipped contact scenarios",
        "criterion": ("no design: the LQR design (impedance.k_env = k_wall) has a pole in the right half-plane "
                      "of its own design model, which the controller refuses (the cell is not run); "
                      f"stable: finite, no contact loss after the first touch, no observer fault, and in the "
                      f"stationary window the contact force's std below {sc.STABLE_STD:.0%} of its mean "
                      "(a bounded, decaying oscillation); overshoot: the transition's peak force over the "
                      "impedance relation's stationary force"),
        "cells": per_cell, "wall_time": {"total_s": wall, "runs": len(jobs)}, "engine": engine_info}
    data["findings"] = map_findings(data)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if plots:
        plot_map(data, out / "force_map.png")
        data["figure"] = "force_map.png"
    (out / "force_map.json").write_text(json.dumps(json_safe(data), indent=2) + "\n")
    return data


def design_poles(path: Path, overrides: Sequence[str]) -> np.ndarray:
    """The poles of the impedance controller's LQR design on its own design model, with the
    scenario's parameters and ``overrides``: the controller computes them the same way
    (``ImpedanceController.setup``: :func:`fmus.force_observer.impedance_math.design_gains` and
    :func:`~fmus.force_observer.impedance_math.closed_loop_poles`) and refuses a design with a
    pole in the right half-plane, so such a cell is reported, not run."""
    from fmus.common.parameters import replace
    from fmus.force_observer import impedance_math as imp
    from orchestration.scenario import scenario_document
    given = scenario_document(path, tuple(overrides))["components"]["impedance"].get("parameters", {})
    d = replace(imp.ImpedanceControllerParameters(), **given)
    return imp.closed_loop_poles(d, imp.design_gains(d), d.k_env)


def map_findings(data: dict[str, Any]) -> list[dict[str, Any]]:
    """The paper's claims judged on the stable cells of the map: ``{claim, ours, reproduced,
    why}`` (``reproduced`` ``"n/a"`` when no cell is stable enough to judge it)."""
    cells = data["cells"]
    out = []
    grid = [(kz, kw) for kz in data["K_z"] for kw in data["k_wall"]]

    def cell(kz: float, kw: float, fb: str) -> dict[str, Any] | None:
        return cells.get(cell_key(kz, kw, fb))

    for fb in data["feedbacks"]:
        stable = [(kz, kw) for kz, kw in grid if cell(kz, kw, fb)["stable"]]
        unstable = [(kz, kw) for kz, kw in grid if not cell(kz, kw, fb)["stable"]]
        errors = {(kz, kw): cell(kz, kw, fb)["steady_F_err"] for kz, kw in stable}
        ok = bool(stable) and all(e <= STEADY_F_LIMIT for e in errors.values())
        out.append({
            "claim": "The LQR impedance controller gives a stable contact whose stationary force follows the "
                     f"impedance relation (Figs. 4, 8), {fb} force in the loop",
            "ours": (f"stable in {len(stable)} of {len(grid)} cells"
                     + (": " + ", ".join(f"K_z {kz:g}/k_wall {kw:g}: {100 * e:.1f} % off, overshoot "
                                         f"{100 * cell(kz, kw, fb).get('overshoot', np.nan):.0f} %"
                                         for (kz, kw), e in errors.items()) if stable else "")
                     + (("; unstable: " + ", ".join(f"K_z {kz:g}/k_wall {kw:g}" for kz, kw in unstable))
                        if unstable else "")),
            "reproduced": ("yes" if ok else "no") if stable else "n/a",
            "why": f"criterion: on every stable cell the stationary force within {STEADY_F_LIMIT:.0%} of the "
                   "impedance relation; the unstable cells are not judged (their stationary force is not one)"})
    if {"observer", "raw"} <= set(data["feedbacks"]):
        judged = [(kz, kw) for kz, kw in grid if cell(kz, kw, "observer")["stable"]]

        def better(kz: float, kw: float) -> bool:
            o, r = cell(kz, kw, "observer"), cell(kz, kw, "raw")
            return not r["stable"] or (o["overshoot"] <= r["overshoot"] and o["contact_losses"] <= r["contact_losses"])

        def text(kz: float, kw: float) -> str:
            o, r = cell(kz, kw, "observer"), cell(kz, kw, "raw")
            raw = (f"{100 * r['overshoot']:.0f} %, {r['contact_losses']} losses, "
                   f"{'stable' if r['stable'] else 'unstable'}" if r["design"] == "stable" else "no design")
            return f"K_z {kz:g}/k_wall {kw:g}: {100 * o['overshoot']:.0f} % vs {raw}"
        out.append({
            "claim": "With the observer the contact transition is free of the inertial effect (Fig. 7): better "
                     "than with the raw reading",
            "ours": ("observer vs raw overshoot: " + "; ".join(text(kz, kw) for kz, kw in judged)
                     if judged else "no cell where the observer's loop is stable"),
            "reproduced": ("yes" if all(better(kz, kw) for kz, kw in judged) else "no") if judged else "n/a",
            "why": "criterion: on every cell where the loop with the observer is stable, the raw reading's loop "
                   "is unstable, or stable with an overshoot and contact losses not smaller"})
    return out


def plot_map(data: dict[str, Any], path: Path) -> None:
    """The map: one panel per force in the loop, ``K_z`` down, ``k_wall`` across, green for a
    stable cell and red for an unstable one, the overshoot (and losses) written in each."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    fbs = data["feedbacks"]
    fig, axes = plt.subplots(1, len(fbs), figsize=(4.6 * len(fbs), 4.2), squeeze=False)
    for ax, fb in zip(axes[0], fbs):
        grid = np.array([[1.0 if data["cells"][cell_key(kz, kw, fb)]["stable"] else 0.0 for kw in data["k_wall"]]
                         for kz in data["K_z"]])
        ax.imshow(grid, cmap=ListedColormap(["#f4a6a6", "#a6dba0"]), vmin=0, vmax=1, origin="lower")
        for i, kz in enumerate(data["K_z"]):
            for j, kw in enumerate(data["k_wall"]):
                ax.text(j, i, _cell_text(data["cells"][cell_key(kz, kw, fb)], "\n"), ha="center", va="center",
                        fontsize=7)
        ax.set_xticks(range(len(data["k_wall"])), [f"{v:g}" for v in data["k_wall"]])
        ax.set_yticks(range(len(data["K_z"])), [f"{v:g}" for v in data["K_z"]])
        ax.set_xlabel("wall stiffness k_wall [N/m]")
        ax.set_ylabel("target stiffness K_z [N/m]")
        ax.set_title(f"{fb} force in the loop")
    fig.suptitle(f"Impedance loop ({data['structure']} controller, compliant tool): stability and overshoot")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def format_map(data: dict[str, Any]) -> str:
    """The map as text: per force in the loop a table of ``K_z`` rows and ``k_wall`` columns."""
    lines = []
    for fb in data["feedbacks"]:
        lines.append(f"{fb} force in the loop (stable, overshoot, contact losses):")
        lines.append("| K_z \\ k_wall | " + " | ".join(f"{v:g}" for v in data["k_wall"]) + " |")
        lines.append("|---" * (len(data["k_wall"]) + 1) + "|")
        for kz in data["K_z"]:
            row = [_cell_text(data["cells"][cell_key(kz, kw, fb)], ", ") for kw in data["k_wall"]]
            lines.append(f"| {kz:g} | " + " | ".join(row) + " |")
    for f in data["findings"]:
        lines.append(f"[{f['reproduced']:>3}] {f['claim']}\n      ours: {f['ours']}\n      why: {f['why']}")
    lines.append(f"{data['wall_time']['runs']} runs in {data['wall_time']['total_s']:.0f} s")
    return "\n".join(lines)


def _cell_text(c: dict[str, Any], sep: str) -> str:
    """One cell in words: stable or not, overshoot and contact losses (or that it has no design)."""
    if c["design"] != "stable":
        return f"no design{sep}(LQR unstable)"
    return (f"{'stable' if c['stable'] else 'unstable'}{sep}{100 * c.get('overshoot', np.nan):.0f} %"
            f"{sep}{c['contact_losses']} losses")


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def register(subparsers: Any) -> None:
    """Add ``flexfusion study force-map``."""
    from orchestration.study import add_engine_arguments, add_executor_arguments
    p = subparsers.add_parser("force-map", help="impedance loop stability: target stiffness K_z against the "
                              "wall's, observer and raw force (impedance paper)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (force_map.json, force_map.png)")
    p.add_argument("--k-z", type=_floats, default=K_Z, metavar="K1,K2,...",
                   help=f"target stiffnesses [N/m] (default {','.join(f'{v:g}' for v in K_Z)})")
    p.add_argument("--k-wall", type=_floats, default=K_WALL, metavar="K1,K2,...",
                   help=f"wall stiffnesses [N/m] (default {','.join(f'{v:g}' for v in K_WALL)})")
    p.add_argument("--structure", choices=sc.STRUCTURES, default="paper",
                   help="impedance controller: the paper's (eqs. 39-41, default) or ours (integral)")
    p.add_argument("--set", action="append", default=[], metavar="COMP.PARAM=VALUE", dest="overrides",
                   help="override a parameter in every cell (repeatable)")
    p.add_argument("--no-plots", action="store_true", help="write force_map.json only")
    add_engine_arguments(p, "cases", sc.CHECK_CASES,
                         batched="the cells of each scenario file together without FMI, a few checked through the FMUs",
                         fmu="one co-simulation of the FMUs per cell")
    add_executor_arguments(p)
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    """Run the map from parsed arguments and print it. Returns the exit code."""
    data = run_map(args.out, args.k_z, args.k_wall, structure=args.structure, overrides=tuple(args.overrides),
                   workers=args.workers, scheduler=args.scheduler, progress=not args.no_progress,
                   plots=not args.no_plots, engine=args.engine, check_cases=args.check_cases)
    print(format_map(data))
    return 0


__all__ = ["K_Z", "K_WALL", "FEEDBACKS", "cell_key", "cell_overrides", "run_map", "map_findings", "plot_map",
           "format_map", "register", "main"]
