"""Contact study: force observer and impedance control through contact (impedance paper).

Three phases as in the paper (section V): free motion (with strong accelerations, true contact
force zero), the contact transition against a wall of 5 N/mm, motion in contact and a
stationary hold. Each scenario is run twice: once with the ForceObserver's estimate in the
impedance loop and once with the raw force-sensor reading.

This module holds

* :func:`contact_metrics` -- the numbers the issue asks for, from time series;
* :func:`plot_contact` -- Figs. 6-8 of the paper (raw force vs observer output, tool
  acceleration, position vs reference);
* :func:`compliant_tool_study` -- the same loop on a one-axis model with a rigid and a
  compliant tool (the paper's Optidrive), to judge whether the compliance matters;
* :func:`run_study` / ``main`` -- run the shipped contact scenarios through the orchestration
  and write ``metrics.json`` and the figures.

Sign convention: forces are those of the tool ON the environment (``-f_ext``), world x, z.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fmus.force_observer import force_observer_math as fom
from fmus.force_observer import impedance_math as imp

REPO = Path(__file__).resolve().parent.parent
SCENARIOS = REPO / "orchestration" / "scenarios"


@dataclass(frozen=True)
class ContactSetup:
    """What the metrics need to know about a contact scenario (SI, world frame)."""

    normal: tuple[float, float] = (1.0, 0.0)   # direction in which the tool pushes
    x_wall: float = 1.30                       # wall position along the normal
    k_wall: float = 5000.0                     # wall stiffness (N/m)
    K_z: float = 2000.0                        # target stiffness of the controller (N/m)
    F_d: float = 0.0                           # desired force bias (N)
    free_window: tuple[float, float] = (0.0, 1.0)     # free-space acceleration phase (s)
    steady_window: tuple[float, float] = (0.0, 1.0)   # stationary contact (s)


def _rms(v: np.ndarray) -> float:
    v = np.asarray(v, dtype=float)
    return float(np.sqrt(np.mean(np.sum(v.reshape(len(v), -1) ** 2, axis=1))))


def contact_losses(F_normal: np.ndarray, threshold: float = 0.0) -> tuple[int, int | None]:
    """Number of contact losses after the first touch and the index of the first touch.

    Contact is ``F_normal > threshold``; a loss is a transition from contact to no contact.
    """
    inc = np.asarray(F_normal) > threshold
    if not inc.any():
        return 0, None
    first = int(np.argmax(inc))
    d = np.diff(inc[first:].astype(int))
    return int(np.sum(d == -1)), first


def contact_metrics(series: dict[str, np.ndarray], setup: ContactSetup) -> dict[str, Any]:
    """The contact study's numbers from one run.

    Parameters
    ----------
    series
        ``t`` (n,), ``F_true`` (n, 2) true force on the environment, ``F_fb`` (n, 2) the force
        in the loop, ``F_hat`` (n, 2) observer estimate, ``F_raw`` (n, 2) raw reading with
        gravity removed, ``p_tool`` (n, 2) true tool position, ``p_ref`` (n, 2) reference.
    setup
        Wall, impedance and analysis windows.

    Returns
    -------
    dict
        ``free_rms_hat``, ``free_rms_raw``, ``free_ratio`` (estimate RMS / raw RMS in the free
        window); ``steady_F_true``, ``steady_F_hat``, ``steady_hat_err`` (relative error of the
        estimate), ``steady_x``, ``pred_x``, ``steady_F``, ``pred_F`` and their relative errors
        (``x`` as penetration ``x - x_wall``); ``first_touch``, ``overshoot`` ((max F - F_s) /
        F_s after first touch), ``contact_losses``; ``finite`` (no NaN anywhere).
    """
    n = np.asarray(setup.normal, float)
    n = n / np.hypot(*n)
    t = np.asarray(series["t"])
    Ft = np.asarray(series["F_true"])
    Fh = np.asarray(series["F_hat"])
    Fr = np.asarray(series["F_raw"])
    p = np.asarray(series["p_tool"])
    pr = np.asarray(series["p_ref"])
    fw = (t >= setup.free_window[0]) & (t <= setup.free_window[1])
    sw = (t >= setup.steady_window[0]) & (t <= setup.steady_window[1])
    out: dict[str, Any] = {}
    out["free_max_true"] = float(np.max(np.abs(Ft[fw]))) if fw.any() else float("nan")
    out["free_rms_hat"] = _rms(Fh[fw])
    out["free_rms_raw"] = _rms(Fr[fw])
    out["free_ratio"] = out["free_rms_hat"] / out["free_rms_raw"]
    Fn_true = Ft @ n
    Fn_hat = Fh @ n
    x = p @ n
    xr_s = float(np.mean(pr[sw] @ n))
    out["steady_F_true"] = float(np.mean(Fn_true[sw]))
    out["steady_F_hat"] = float(np.mean(Fn_hat[sw]))
    out["steady_hat_err"] = abs(out["steady_F_hat"] - out["steady_F_true"]) / abs(out["steady_F_true"])
    x_pred, F_pred = imp.stationary_contact(setup.K_z, setup.k_wall, xr_s, setup.x_wall, setup.F_d)
    out["steady_x_pen"] = float(np.mean(x[sw])) - setup.x_wall
    out["pred_x_pen"] = x_pred - setup.x_wall
    out["steady_x_err"] = abs(out["steady_x_pen"] - out["pred_x_pen"]) / abs(out["pred_x_pen"])
    out["steady_F"] = out["steady_F_true"]
    out["pred_F"] = F_pred
    out["steady_F_err"] = abs(out["steady_F"] - F_pred) / abs(F_pred)
    losses, first = contact_losses(Fn_true)
    out["contact_losses"] = losses
    out["first_touch"] = float(t[first]) if first is not None else None
    if first is not None:
        after = (t >= t[first]) & (t < setup.steady_window[0])
        F_max = float(np.max(Fn_true[after])) if after.any() else float("nan")
        out["F_max_transition"] = F_max
        out["overshoot"] = (F_max - F_pred) / F_pred
    out["finite"] = bool(all(np.all(np.isfinite(np.asarray(series[k]))) for k in
                             ("F_hat", "F_fb", "p_tool") if k in series))
    return out


def plot_contact(runs: dict[str, dict[str, np.ndarray]], setup: ContactSetup, out_dir: Path,
                 prefix: str = "contact") -> list[Path]:
    """Figs. 6-8 of the paper for each run (``runs``: label -> series of :func:`contact_metrics`
    plus ``a_meas`` (n, 2), tool acceleration from the accelerometer).

    Fig. 6/7 (top): raw force vs observer output along the normal; Fig. 7 (bottom): tool
    acceleration and the observer's compensation (raw - estimate); Fig. 8: position along the
    normal vs reference, with the wall.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    n = np.asarray(setup.normal, float) / np.hypot(*setup.normal)
    files = []
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for label, s in runs.items():
        t = s["t"]
        axes[0, 0].plot(t, s["F_raw"] @ n, lw=0.8, label=label)
        axes[0, 1].plot(t, s["F_hat"] @ n, lw=0.8, label=label)
        axes[1, 0].plot(t, s["a_meas"] @ n, lw=0.8, label=label)
        axes[1, 1].plot(t, (s["F_raw"] - s["F_hat"]) @ n, lw=0.8, label=label)
    first = next(iter(runs.values()))
    axes[0, 1].plot(first["t"], first["F_true"] @ n, "k--", lw=0.8, label="true contact force")
    axes[0, 0].set_title("force sensor reading (gravity removed) [N]")
    axes[0, 1].set_title("force observer output [N]")
    axes[1, 0].set_title("tool acceleration (accelerometer) [m/s²]")
    axes[1, 1].set_title("observer compensation (raw − estimate) [N]")
    for ax in axes.flat:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes[1]:
        ax.set_xlabel("t [s]")
    fig.suptitle("Contact force along the normal (cf. paper Figs. 6-7)")
    fig.tight_layout()
    f = out_dir / f"{prefix}_fig6_7_force_acceleration.png"
    fig.savefig(f, dpi=120)
    plt.close(fig)
    files.append(f)

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for label, s in runs.items():
        ax.plot(s["t"], 1e3 * (s["p_tool"] @ n), lw=0.9, label=f"position ({label})")
    ax.plot(first["t"], 1e3 * (first["p_ref"] @ n), "k--", lw=0.9, label="reference")
    ax.axhline(1e3 * setup.x_wall, color="r", lw=0.8, label="wall")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("position along the normal [mm]")
    ax.set_title("Reference and tool position (cf. paper Fig. 8)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    f = out_dir / f"{prefix}_fig8_position.png"
    fig.savefig(f, dpi=120)
    plt.close(fig)
    files.append(f)
    return files


# ---------------------------------------------------------------------------------------------
# rigid vs compliant tool on the one-axis model
# ---------------------------------------------------------------------------------------------
def compliant_tool_study(design: imp.ImpedanceDesign | None = None, speed: float = 0.05,
                         t_end: float = 5.0) -> dict[str, dict[str, Any]]:
    """Close the impedance loop on :class:`imp.OneAxisPlant` with a rigid and with a compliant
    tool (12 kg on 3e4 N/m, damping ratio 0.3: an 8 Hz Optidrive-like mount), observer vs raw.

    Cases: ``rigid`` (rigid tool, rigid design), ``compliant`` (compliant tool, controller
    designed for a rigid one, tool position fed back) and ``compliant_designed`` (compliant
    tool in the LQR design model, as the paper's eq. 39, flange position and deflection fed
    back). Returns per case and feedback the contact losses after first touch, the peak force,
    the final force against the prediction and the peak tool speed (a loop that went unstable
    shows up as a large one).
    """
    d = design or imp.ImpedanceDesign()
    kc, dc, mt = 3e4, 360.0, 12.0
    x0, x1 = -0.05, 0.02
    T = 1.875 * (x1 - x0) / speed
    ref = imp.smooth_ramp(x0, x1, 0.2, 0.2 + T)
    res: dict[str, dict[str, Any]] = {}
    for case in ("rigid", "compliant", "compliant_designed"):
        plant = imp.OneAxisPlant(compliant=case != "rigid", k_c=kc, d_c=dc, m_t=mt)
        dd = imp.replace_design(d, tool_m=mt, tool_k=kc, tool_d=dc) if case == "compliant_designed" else d
        _, F_pred = imp.stationary_contact(d.K_z, plant.k_w, x1, plant.x_w)
        for fb in ("observer", "raw"):
            o = imp.simulate_1dof(plant, dd, ref, t_end + T, observer="static", use_raw=fb == "raw")
            losses, _ = contact_losses(o["F"])
            res[f"{case}/{fb}"] = dict(contact_losses=losses, F_max=float(o["F"].max()),
                                       F_end=float(o["F"][-1]), F_pred=F_pred,
                                       v_max=float(np.abs(o["v"]).max()))
    return res


def one_axis_reference(x_wall: float = 0.0):
    """The three phases on one axis: free back-and-forth motion (strong accelerations),
    approach and contact transition at 50 mm/s, motion in contact (the reference moves 10 mm
    further into the wall), then a hold. Returns ``(x_ref(t), t_end, ContactSetup)``."""
    x_far = x_wall - 0.10
    legs = [(x_far, x_far - 0.15, 0.3, 0.8), (x_far - 0.15, x_far, 0.8, 1.3),       # free, fast
            (x_far, x_wall + 0.01, 1.8, 1.8 + 1.875 * 0.11 / 0.05),                  # approach
            (x_wall + 0.01, x_wall + 0.02, 7.0, 8.0)]                                # in contact
    ramps = [imp.smooth_ramp(a, b, t0, t1) for a, b, t0, t1 in legs]

    def x_ref(t: float) -> float:
        return x_far + sum(r(t) - a for r, (a, *_rest) in zip(ramps, legs))
    setup = ContactSetup(normal=(1.0, 0.0), x_wall=x_wall, free_window=(0.25, 1.5),
                         steady_window=(10.0, 11.0))
    return x_ref, 11.0, setup


def run_study_1dof(out_dir: Path | None = None, noise_f: float = 0.5, noise_a: float = 0.05,
                   seed: int = 0) -> dict[str, Any]:
    """The contact study on the one-axis model (rigid tool): observer vs raw reading in the
    loop; metrics of :func:`contact_metrics` per run and, with ``out_dir``, Figs. 6-8."""
    x_ref, t_end, setup = one_axis_reference()
    d = imp.ImpedanceDesign(K_z=setup.K_z)
    plant = imp.OneAxisPlant(x_w=setup.x_wall, k_w=setup.k_wall)
    runs, metrics = {}, {}
    for label, raw in (("observer", False), ("raw", True)):
        o = imp.simulate_1dof(plant, d, x_ref, t_end, x0=x_ref(0.0), observer="lowpass", use_raw=raw,
                              noise_f=noise_f, noise_a=noise_a, seed=seed)
        z = np.zeros_like(o["t"])
        two = lambda v: np.column_stack([v, z])
        series = dict(t=o["t"], F_true=two(o["F"]), F_hat=two(o["F_hat"]), F_raw=two(o["u"]),
                      F_fb=two(o["u"] if raw else o["F_hat"]), p_tool=two(o["x"]),
                      p_ref=two(o["x_ref"]), a_meas=two(o["a"]))
        runs[label] = series
        metrics[label] = contact_metrics(series, setup)
    if out_dir is not None:
        plot_contact(runs, setup, Path(out_dir), prefix="one_axis")
    return metrics


# ---------------------------------------------------------------------------------------------
# the study on the real plant (through the orchestration)
# ---------------------------------------------------------------------------------------------
def run_study(out_dir: Path, scenarios: tuple[str, ...] = ("contact_observer", "contact_raw"),
              stop_time: float | None = None) -> dict[str, Any]:
    """Run the shipped contact scenarios, compute :func:`contact_metrics`, plot Figs. 6-8."""
    from orchestration import contact_runner  # noqa: F401 - placeholder until integration
    raise NotImplementedError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="study_contact", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "results" / "contact")
    parser.add_argument("--compliant", action="store_true",
                        help="only the one-axis rigid vs compliant tool comparison")
    parser.add_argument("--one-axis", action="store_true",
                        help="only the contact study on the one-axis model")
    args = parser.parse_args(argv)
    if args.compliant:
        print(json.dumps(compliant_tool_study(), indent=2))
        return 0
    if args.one_axis:
        print(json.dumps(run_study_1dof(args.out), indent=2))
        return 0
    metrics = run_study(args.out)
    print(json.dumps(metrics, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
