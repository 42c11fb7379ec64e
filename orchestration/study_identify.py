"""Identification of the estimators' robot model from experiments on the simulated plant.

As on a real robot (Henriksson 2009, section IV: the observers' model parameters "come from a
separate identification procedure"; Wernholt & Moberg 2008), the study

1. runs the experiment scenario (``identify_experiment.toml``: the plant FMU with the motion
   controller in identification mode - a multisine torque added to its output - the Encoder and
   the Imu) at several working points, one run each on the study executor;
2. fits the 8-state flexible-joint model to what a real identification sees - the commanded
   motor torque's known controller law, the encoder angles and the accelerometer - by
   closed-loop output error (:mod:`orchestration.identification`, which also says why), the
   model's simulation of each experiment and of each Jacobian column on the same executor.
   By default as a practitioner would (:data:`~orchestration.identification.PRACTICE`): the
   output error prefiltered to the band the model is meant for (``--prefilter HZ``, 0 = off)
   and the accelerometer's calibration (scale, mounting cross-axis terms, bias) estimated with
   the robot (``--no-acc-calibration``: use the nominal mounting instead). The Imu's
   ``mount_rpy`` and ``acc_scale`` in the scenario are the sensor's true errors and are never
   read: the fit assumes the nominal mounting (identity);
3. reports the fitted values beside the plant's true ones (read from the scenario: the
   simulation's privilege, used for the report only, never in the fit), with one standard
   deviation and a 95 % interval from the autocorrelation-consistent covariance
   (:mod:`orchestration.identification`, *Uncertainty*; the former white-residual one beside it
   as ``std_white``), whether each interval covers the true value and whether each estimate is
   biased (error beyond 3 std), in ``identify.json``; with ``--effective`` also the effective
   values the reduced model reaches on this plant (the fitted values of a noise-free, long
   identification run with ``--noise-free``) and whether each interval covers them;
4. writes the identified :class:`RobotParameters` as the parameter set ``identified_robot``
   (``[parameter_sets.identified_robot]``, see :mod:`orchestration.scenario`) of an include
   file that the paper scenarios use.

The plant is whatever the scenario (and ``--set plant.<param>=...``) makes it: on a plant with
dynamics the model lacks (parameter ``ideal = false`` where the plant has it), the estimates
are biased and ``identify.json`` says so.

CLI::

    flexfusion study identify [SCENARIO] --out DIR [--working-point X,Z ...] [--amplitude A]
        [--stop-time S] [--max-nfev N] [--prefilter HZ] [--no-acc-calibration] [--include FILE]
        [--noise-free | --effective IDENTIFY_JSON]
        [--set COMP.PARAM=VALUE ...] [--workers K | --scheduler ADDR]

writes ``DIR/identify.json`` and the include file (default ``DIR/identified_robot.toml``). A
fit that does not converge ends in one ``error:`` line (exit 2) with the best fit so far in
``DIR/identify.json``.
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Sequence

from fmus.common.parameters import ParameterError, validate

from . import identification as ident
from .scenario import override_strings
from .study import (StudyError, add_executor_arguments, dataclass_from_scalars, map_jobs,
                    open_executor, require_recorded, simulate)

SCENARIOS = Path(__file__).resolve().parent / "scenarios"
DEFAULT_SCENARIO = SCENARIOS / "identify_experiment.toml"
SET_NAME = "identified_robot"

#: Working points (tool x, z in m): the shoulder's gravity torque near zero (its soft spring
#: zone and its gravity moment), the forearm near vertical (the elbow's soft zone), and the
#: arm stretched out under full gravity load (high stiffness, large inertia).
WORKING_POINTS: tuple[tuple[float, float], ...] = ((0.7, 1.3), (0.9, -0.6), (1.4, 0.3))
#: Sensor settings of a noise-free experiment (``--noise-free``): the effective values.
NOISE_FREE = (("Encoder", "noise=0"), ("Encoder", "resolution=0"), ("Imu", "acc_noise=0"),
              ("Imu", "acc_resolution=0"), ("Imu", "acc_bias_rw=0"))
BIAS_LIMIT = 3.0          #: an error beyond this many standard deviations is called biased ...
#: What "true" means on a plant with unmodelled dynamics (identify.json, ``plant.true_values``).
TRUE_VALUES_NOTE = (
    "'true' is the plant's gearbox / nominal value. On the realistic plant the 8-state model's "
    "stiffness, damping and inertia are effective values: the link bending adds compliance in series "
    "with the gearbox (the arm beyond the bending joint sees the two springs in series, quasi-statically), "
    "so the model that reproduces the plant has a lower k_lo, k_hi and d than the gearbox; a relative "
    "error of those against 'true' is partly that series compliance, not an identification error. "
    "Likewise the torque-constant error (tau_applied = (1 + e) tau_m): the model that explains the motion "
    "from the commanded torque, which is what the estimators receive, has the joint's torque-related "
    "parameters (gravity moments, inertias, friction) about e lower; switched off, moment_g1's error "
    "goes from -4.8 % to -2.1 %. Judge those errors against the plant's value with that in mind.")
RESOLUTION = 1e-6         #: ... if it also exceeds the optimiser's resolution (relative; xtol 1e-8
                          #: in log space): noise-free data have std near rounding error


# ---------------------------------------------------------------------------------------------
# experiments
# ---------------------------------------------------------------------------------------------
def experiment_overrides(k: int, point: Sequence[float], amplitude: float | None, controller: str = "controller",
                         plant: str = "plant") -> list[str]:
    """Overrides of experiment ``k`` at the working point ``point``: path start, initial pose,
    its own excitation seed and noise seed (``controller``, ``plant``: component names)."""
    point = [float(v) for v in point]
    out = {(controller, "path_start"): point, (plant, "p_tool0"): point,
           (controller, "excitation_seed"): k, ("scenario", "seed"): k + 1}
    if amplitude is not None:
        out[(controller, "excitation_amplitude")] = [float(amplitude)] * 2
    return list(override_strings(out))


def recorded(sc: Any) -> list[str]:
    """What the fit reads: the commanded torque, the encoder angles, the accelerometer."""
    return [f"{_component(sc, fmu).name}.{var}" for fmu, var in
            (("MotionController", "tau_m"), ("Encoder", "q_m_meas"), ("Imu", "acc_s"))]


def _component(sc: Any, fmu: str) -> Any:
    found = [c for c in sc.components.values() if c.model_identifier == fmu]
    if len(found) != 1:
        raise StudyError(f"scenario '{sc.name}' needs exactly one {fmu} component, found {len(found)}")
    return found[0]


def _experiment(name: str, sc: Any, run: Any) -> ident.Experiment:
    """The :class:`~orchestration.identification.Experiment` of one run: the controller's and
    the accelerometer's data-sheet settings (filter, gravity) from the scenario, the recorded
    signals; the accelerometer at its nominal mounting (the Imu's ``mount_rpy`` is its unknown
    true misalignment)."""
    from fmus.robot_plant.sensor_model import ImuParameters
    from fmus.robot_plant.motion_control_model import MotionControllerParameters
    ctrl, imu, enc = (_component(sc, f) for f in ("MotionController", "Imu", "Encoder"))
    for c in (ctrl, imu, enc):
        if c.step != sc.base_step:
            raise StudyError(f"component '{c.name}': the identification needs every component at the "
                             f"base step {sc.base_step:g} s, not {c.step:g} s")
    for c in (imu, enc):
        if c.parameters.get("sample_rate", 0.0):
            raise StudyError(f"component '{c.name}': the identification needs sample_rate = 0 "
                             "(a sample every step)")
    imu_p = dataclass_from_scalars(ImuParameters, imu.parameters)
    return ident.Experiment(
        name, run.time, run[f"{ctrl.name}.tau_m"], run[f"{enc.name}.q_m_meas"], run[f"{imu.name}.acc_s"],
        dataclass_from_scalars(MotionControllerParameters, ctrl.parameters),
        acc_cutoff=imu_p.acc_cutoff, acc_filter_order=imu_p.filter_order, g=imu_p.g)


def noise_levels(sc: Any) -> ident.NoiseLevels:
    """Whitening levels from the sensors' data-sheet settings in the scenario."""
    from fmus.robot_plant.sensor_model import EncoderParameters
    from fmus.robot_plant.sensor_model import ImuParameters
    enc = dataclass_from_scalars(EncoderParameters, _component(sc, "Encoder").parameters)
    imu = dataclass_from_scalars(ImuParameters, _component(sc, "Imu").parameters)
    return ident.NoiseLevels.of_sensors(enc.noise, enc.resolution, imu.acc_noise, imu.acc_resolution)


def run_experiments(scenario: str | Path, points: Sequence[Sequence[float]], executor: Any, *,
                    overrides: Sequence[str] = (), amplitude: float | None = None,
                    progress: bool = True) -> tuple[list[ident.Experiment], Any]:
    """Run the experiment at every working point; returns the experiments and the loaded
    scenario of the first (for the sensors' and the plant's settings)."""
    from .scenario import load_scenario
    from .study_tune import load_document
    doc = load_document(scenario)
    sc = load_scenario(doc, overrides)                        # bad input fails here, once
    require_recorded(sc, recorded(sc), "the identification")
    names = {"controller": _component(sc, "MotionController").name,
             "plant": _component(sc, "FlexibleRobot2DOF").name}
    per_exp = [list(overrides) + experiment_overrides(k, pt, amplitude, **names) for k, pt in enumerate(points)]
    scenarios = [load_scenario(doc, ov) for ov in per_exp]
    runs = map_jobs(simulate, [(doc, ov, recorded(sc)) for ov in per_exp], executor, star=True,
                    desc="identification experiments", progress=progress)
    exps = [_experiment(f"working point {tuple(pt)}", sc, run) for pt, sc, run in zip(points, scenarios, runs)]
    return exps, scenarios[0]


# ---------------------------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------------------------
def plant_truth(sc: Any) -> tuple[Any, bool | None]:
    """The plant's robot parameters and its ``ideal`` flag (None: the plant has no such
    parameter, i.e. no unmodelled dynamics) - for the report only."""
    from fmus.robot_plant.plant_model import PlantParameters
    plant = _component(sc, "FlexibleRobot2DOF")
    params = dataclass_from_scalars(PlantParameters, plant.parameters)
    ideal = getattr(params, "ideal", None) if "ideal" in plant.variables else None
    return params.robot(), ideal


Z95 = 1.959963984540054   #: the two-sided 95 % quantile of the standard normal


def _std_log(fit: ident.Fit, name: str) -> float:
    """The std of ``log(value)`` of ``name`` (the fit's own, or from ``std / value``)."""
    if fit.std_log is not None:
        return fit.std_log[name]
    return fit.std[name] / fit.values[name]


def _interval(value: float, half: float) -> list[float | None]:
    """``value exp(+-half)``; an upper end beyond floating point is None (unbounded)."""
    return [value * math.exp(-half), value * math.exp(half) if half < 700.0 else None]


def _judge(value: float, std_log: float, target: float, cv: float = Z95) -> tuple[float | None, bool | None]:
    """Error of ``value`` against ``target`` in std of ``log`` and whether the 95 % interval
    ``value exp(+-cv std_log)`` covers ``target`` (None, None if the std is not finite)."""
    if not math.isfinite(std_log):
        return None, None
    err = abs(math.log(value / target))
    z = err / std_log if std_log > 0 else (0.0 if err == 0.0 else math.inf)
    return z, bool(err <= cv * std_log)


def report(fit: ident.Fit, true: Any, ideal: bool | None, effective: dict[str, Any] | None = None
           ) -> dict[str, Any]:
    """``identify.json``'s content: per fitted parameter the fitted and true value, std (the
    autocorrelation-consistent one, :func:`~orchestration.identification.hac_covariance`, and
    the white-residual ``s^2 (J^T J)^-1`` one for comparison), the 95 % interval (in ``log``
    space, where the fit runs), whether it covers the true value, relative error and whether it is
    biased (with the reason); with ``effective`` (:func:`load_effective`) also the effective
    values a noise-free fit reaches and whether the interval covers them; the parameters held
    fixed and why; the fit."""
    unmodelled = ideal is False
    true_values = dict(zip(ident.NAMES, ident.parameter_values(true)))
    eff_values = None if effective is None else effective["values"]
    cv = fit.critical_value
    params: dict[str, Any] = {}
    for name in ident.NAMES:
        v, t, s = fit.values[name], float(true_values[name]), fit.std[name]
        sl = _std_log(fit, name)
        bound = (fit.at_bound or {}).get(name)
        z, covers = _judge(v, sl, t, cv)
        if bound is not None:               # not determined: the stated range is the interval
            covers = bool(bound[0] <= t <= bound[1])
        biased = bool(z is not None and not z <= BIAS_LIMIT and abs(v / t - 1.0) > RESOLUTION)
        if bound is not None:
            biased = False
            reason = (f"on the bound of its stated range {bound[0]:g}-{bound[1]:g}: not determined by these "
                      "experiments; the range is its interval")
        elif z is None:
            s = None
            reason = "not determined by these experiments (infinite std): add a working point that excites it"
        elif biased:
            reason = f"error {z:.1f} std (> {BIAS_LIMIT:g})"
            reason += (": the plant has dynamics the model lacks (ideal = false)" if unmodelled else
                       ": the model matches the plant's structure; the excitation or the noise model "
                       "is insufficient")
        elif z <= BIAS_LIMIT:
            reason = f"error {z:.1f} std, within {BIAS_LIMIT:g}"
        else:
            reason = f"error {abs(v / t - 1.0):.1e} relative, below the fit's resolution {RESOLUTION:g}"
        entry = {"fitted": v, "true": t, "std": s, "relative_error": v / t - 1.0,
                 "relative_std": None if s is None else s / v, "error_in_std": z,
                 "interval95": (list(bound) if bound is not None else None if s is None else
                                _interval(v, cv * sl)),
                 "at_bound": bound is not None,
                 "covers_true": covers, "biased": biased, "reason": reason}
        if fit.std_log_white is not None:
            zw, cw = _judge(v, fit.std_log_white[name], t)
            entry["std_white"] = fit.std_white[name] if zw is not None else None
            entry["white_covers_true"] = cw
        if eff_values is not None:
            e = float(eff_values[name])
            ze, ce = _judge(v, sl, e, cv)
            if bound is not None:
                ce = bool(bound[0] <= e <= bound[1])
            entry.update({"effective": e, "effective_relative_to_true": e / t - 1.0,
                          "relative_error_to_effective": v / e - 1.0, "error_in_std_to_effective": ze,
                          "covers_effective": ce})
        params[name] = entry
    fitted_phys = ident.physical_parameters(fit.robot)
    true_phys = ident.physical_parameters(true)
    derived = {n: {"fitted": fitted_phys[n], "true": true_phys[n]} for n in ("c1", "c2", "I1", "I2")}
    fixed = {n: {"value": fitted_phys[n], "true": true_phys[n], "equal_to_true": fitted_phys[n] == true_phys[n],
                 "reason": f"fixed at the nominal value (not fitted): {ident.FIXED_REASONS[n]}"}
             for n in ident.FIXED}
    rep = {
        "plant": {"ideal": ideal, "unmodelled_dynamics": unmodelled,
                  "note": ("the plant has dynamics the model lacks (elastic mode, torque ripple, "
                           "torque-constant and kinematic errors): estimates are biased" if unmodelled else
                           "the plant has no dynamics beyond the model's structure"),
                  "true_values": TRUE_VALUES_NOTE if unmodelled else "the plant's own parameters"},
        "fit": {"converged": fit.converged, "message": fit.message, "cost": fit.cost, "s2": fit.s2,
                "n_residuals": fit.n_residuals, "nfev": fit.nfev,
                "correlated": _correlated(fit.correlation)},
        "uncertainty": {"method": COVARIANCE_NOTE, "bartlett_lag": fit.hac_lag,
                        "samples_per_experiment": fit.hac_samples, "critical_value": cv,
                        "coverage": _coverage(params, eff_values is not None)},
        "parameters": params,
        "derived": derived,
        "fixed": fixed,
        "biased": [n for n, p in params.items() if p["biased"]],
        "identified_robot": fitted_phys,
        "acc_calibration": _calibration(fit.acc_calibration),
    }
    if effective is not None:
        rep["effective"] = {k: v for k, v in effective.items() if k != "values"}
    return rep


#: identify.json's ``uncertainty.method``.
COVARIANCE_NOTE = (
    "std and interval95 from the autocorrelation-consistent sandwich covariance "
    "(J^T J)^-1 J^T Omega J (J^T J)^-1, Omega from the scores' autocovariances per experiment with "
    "Bartlett weights and the Newey-West (1994) automatic lag (bartlett_lag, in decimated samples), "
    "residuals leverage-adjusted (HC2); interval95 = fitted * exp(+-critical_value * std of log(value)) "
    "(the fit runs in log space), critical_value the fixed-b value of Kiefer & Vogelsang (2005) for "
    "the lag over samples_per_experiment (1.96 for a known variance); std_white is the "
    "former s^2 (J^T J)^-1 (white residuals), kept for comparison. Covers the noise only: on a plant "
    "with dynamics the model lacks, compare with the effective values, not with 'true'.")


def _coverage(params: dict[str, Any], with_effective: bool) -> dict[str, Any]:
    """How many 95 % intervals cover the true (and the effective) values, of those determined."""
    def count(key: str) -> dict[str, Any]:
        got = [p[key] for p in params.values() if p.get(key) is not None]
        return {"covered": sum(got), "of": len(got),
                "not_covered": [n for n, p in params.items() if p.get(key) is False]}
    out = {"true": count("covers_true")}
    if any("white_covers_true" in p for p in params.values()):
        out["true_white_covariance"] = count("white_covers_true")
    if with_effective:
        out["effective"] = count("covers_effective")
    return out


def load_effective(path: Path) -> dict[str, Any]:
    """The effective values of the reduced model on this plant: the fitted values of a noise-free
    (ideally long) identification's ``identify.json`` at ``path`` (written by this study with the
    sensors' noise, quantisation and bias walk off, ``--set`` as docs/user_guide.md says), with
    where they came from. Raises :class:`StudyError` naming the cause if the file is not such a report."""
    try:
        doc = json.loads(Path(path).read_text())
        values = {n: float(doc["parameters"][n]["fitted"]) for n in ident.NAMES}
    except FileNotFoundError:
        raise StudyError(f"--effective {path}: no such file") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise StudyError(f"--effective {path}: not an identify.json with every fitted parameter "
                         f"({type(exc).__name__}: {exc})") from None
    if not all(math.isfinite(v) and v > 0 for v in values.values()):
        raise StudyError(f"--effective {path}: fitted values must be finite and positive")
    exps = doc.get("experiments", {})
    return {"values": values, "source": str(path), "experiments": exps,
            "converged": doc.get("fit", {}).get("converged"),
            "note": "effective values: what the reduced model reaches on this plant from a noise-free "
                    "fit (no noise, so no variance; the difference to 'true' is the model's structural "
                    "bias). covers_effective says whether this fit's 95 % interval contains them."}


def _calibration(cal: Any) -> dict[str, Any] | None:
    """The accelerometer calibration the fit estimated (None if not): per sensor axis the
    reading ``= sum_i C[i] f_i + bias`` with ``f`` the nominally mounted reading; ``scale`` the
    diagonal minus one, ``cross`` the off-diagonal terms (small mounting angles, rad)."""
    if cal is None:
        return None
    c = [[float(v) for v in row] for row in cal]
    return {"matrix": c[:3], "bias": c[3], "scale_x": c[0][0] - 1.0, "scale_z": c[2][2] - 1.0,
            "cross_xz": c[0][2], "cross_zx": c[2][0],
            "note": "reading[j] = sum_i matrix[i][j] * f_nominal[i] + bias[j] (i, j: sensor x, y, z); "
                    "f_nominal has no y component, so matrix[1] is undetermined (zero)"}


def _correlated(corr: Any, limit: float = 0.9) -> list[list[Any]]:
    """Pairs of fitted parameters whose estimates correlate beyond ``limit`` (nearly the same
    information in the data), with the correlation."""
    if corr is None:
        return []
    n = len(ident.NAMES)
    return [[ident.NAMES[i], ident.NAMES[j], float(corr[i, j])] for i in range(n) for j in range(i + 1, n)
            if abs(corr[i, j]) > limit and abs(corr[i, j]) != float("inf")]


def write_include(path: Path, fit: ident.Fit, header: str) -> Path:
    """The identified parameters as ``[parameter_sets.identified_robot]`` of an include file."""
    from .scenario import toml_value
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines.append(f"[parameter_sets.{SET_NAME}]")
    fitted = {n.split("[")[0] for n in ident.NAMES} | {"c1", "c2", "I1", "I2"}
    for name, value in ident.physical_parameters(fit.robot).items():
        note = "identified" if name in fitted else "nominal (fixed)"
        lines.append(f"{name} = {toml_value(value)}   # {note}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def _describe(criterion: ident.Criterion) -> str:
    return ", ".join([f"prefilter {criterion.prefilter:g} Hz" if criterion.prefilter else "no prefilter",
                      "accelerometer calibration estimated" if criterion.acc_calibration
                      else "accelerometer at its nominal mounting"])


def _coverage_line(cov: dict[str, Any]) -> str:
    """One line: how many 95 % intervals cover the true (and effective) values."""
    parts = [f"the true values {cov['true']['covered']}/{cov['true']['of']}"]
    if "true_white_covariance" in cov:
        c = cov["true_white_covariance"]
        parts.append(f"(with the white-residual s^2 (J^T J)^-1: {c['covered']}/{c['of']})")
    if "effective" in cov:
        parts.append(f"the effective values {cov['effective']['covered']}/{cov['effective']['of']}")
    return "95 % intervals covering " + ", ".join(parts)


def _summary(rep: dict[str, Any]) -> str:
    eff = any("effective" in p for p in rep["parameters"].values())
    rows = [f"{'parameter':<14}{'fitted':>13}{'true':>13}" + (f"{'effective':>13}" if eff else "")
            + f"{'rel. err':>10}{'rel. std':>10}  biased  covers" + (" true/eff." if eff else "")]
    for name, p in rep["parameters"].items():
        rel_std = "inf" if p["relative_std"] is None else f"{p['relative_std']:.1e}"
        yn = {True: "yes", False: "no", None: "-"}
        rows.append(f"{name:<14}{p['fitted']:>13.6g}{p['true']:>13.6g}"
                    + (f"{p['effective']:>13.6g}" if eff else "")
                    + f"{p['relative_error']:>+10.2e}{rel_std:>10}  {yn[p['biased']]:<6}  {yn[p['covers_true']]}"
                    + (f"/{yn[p['covers_effective']]}" if eff else ""))
    return "\n".join(rows)


# ---------------------------------------------------------------------------------------------
# the study
# ---------------------------------------------------------------------------------------------
def identify(scenario: str | Path, out: Path, executor: Any, *, points: Sequence[Sequence[float]] = WORKING_POINTS,
             overrides: Sequence[str] = (), amplitude: float | None = None, max_nfev: int = 60,
             criterion: ident.Criterion = ident.PRACTICE, include: Path | None = None, command: str = "",
             progress: bool = True, effective: dict[str, Any] | None = None,
             noise_free: bool = False) -> dict[str, Any]:
    """Run the experiments, fit, write ``out/identify.json`` and the include file; ``effective``
    (:func:`load_effective`) adds the effective values and their coverage to the report;
    ``noise_free`` runs the experiments with :data:`NOISE_FREE` sensors, the whitening keeping
    the sensors' data-sheet levels (so the fit weighs the outputs as with noise): the effective
    values of the reduced model on this plant.

    Raises
    ------
    StudyError
        If the fit does not converge (``identify.json`` then holds the best fit so far) or the
        identified parameters are not physically consistent.
    """
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    quiet = []
    if noise_free:
        from .scenario import load_scenario
        from .study_tune import load_document
        sc0 = load_scenario(load_document(scenario), overrides)
        levels = noise_levels(sc0)
        quiet = [f"{_component(sc0, fmu).name}.{o}" for fmu, o in NOISE_FREE]
    exps, sc = run_experiments(scenario, points, executor, amplitude=amplitude, progress=progress,
                               overrides=list(overrides) + quiet)
    if not noise_free:
        levels = noise_levels(sc)
    t_exp = time.perf_counter() - t0
    nominal = exps[0].controller.robot()          # the controller's own (CAD) model of the robot

    def map_fn(fn: Any, jobs: list[tuple]) -> list[Any]:
        return map_jobs(fn, jobs, executor, star=True, progress=False)

    def show(cost: float) -> None:
        if progress:
            print(f"  residual evaluation: cost {cost:.6g}", file=sys.stderr)

    true, ideal = plant_truth(sc)
    json_path = out / "identify.json"
    try:
        fit = ident.fit(exps, nominal, noise=levels, criterion=criterion, max_nfev=max_nfev,
                        map_fn=map_fn, progress=show)
    except ValueError as exc:                       # a criterion the data cannot have
        raise StudyError(str(exc)) from None
    except ident.IdentificationError as exc:
        rep = report(exc.best, true, ideal, effective) if exc.best is not None else {"fit": {"converged": False}}
        rep["error"] = str(exc)
        json_path.write_text(json.dumps(rep, indent=1))
        raise StudyError(f"{exc} (written to {json_path})") from None
    wall = time.perf_counter() - t0
    rep = report(fit, true, ideal, effective)
    rep["criterion"] = dataclasses.asdict(criterion)
    rep["experiments"] = {"working_points": [list(map(float, p)) for p in points],
                          "duration": float(exps[0].time[-1]), "overrides": list(overrides),
                          "wall_time_experiments": t_exp}
    rep["wall_time"] = wall
    rep["noise_free"] = noise_free
    json_path.write_text(json.dumps(rep, indent=1))
    try:
        validate(fit.robot)
    except ParameterError as exc:
        raise StudyError(f"the identified parameters are not physically consistent: {exc} "
                         f"(fit written to {json_path})") from None
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    biased = ", ".join(rep["biased"]) or "none"
    worst = max(abs(p["relative_error"]) for p in rep["parameters"].values())
    header = (f"Robot model identified on the simulated plant by:\n  {command or 'flexfusion study identify'}\n"
              f"on {date}: {len(exps)} experiments of {exps[0].time[-1]:g} s at the working points "
              f"{', '.join(str(tuple(p)) for p in points)};\n"
              f"closed-loop output error ({_describe(criterion)}), s^2 = {fit.s2:.3g}, "
              f"{fit.nfev} residual evaluations, {wall:.0f} s; largest relative error against the plant {worst:.2e}; biased: {biased}.\n"
              f"Plant: {rep['plant']['note']}.\n"
              f"Scenarios use it with include = [\"identified_robot.toml\"] and, per component,\n"
              f"parameter_sets = [\"{SET_NAME}\"]. To give every estimator its FMU defaults (the\n"
              f"nominal values, those of the default plant) instead: --set parameter_sets.{SET_NAME}={{}}\n"
              f"(or per component --set COMP.parameter_sets=[]).\n")
    write_include(include or out / f"{SET_NAME}.toml", fit, header + "\n" + _summary(rep) + "\n")
    return rep


def main(args: argparse.Namespace) -> int:
    points = [parse_point(p) for p in args.working_point] if args.working_point else list(WORKING_POINTS)
    try:
        args.criterion = dataclasses.replace(ident.PRACTICE, prefilter=args.prefilter,
                                             acc_calibration=not args.no_acc_calibration)
    except ValueError as exc:
        raise StudyError(f"--prefilter {args.prefilter:g}: {exc}") from None
    overrides = list(args.set or [])
    if args.noise_free and args.effective:
        raise StudyError("--noise-free computes effective values; --effective compares with them: give one")
    if args.stop_time is not None:
        overrides.append(f"scenario.stop_time={args.stop_time}")
    out = Path(args.out)
    effective = load_effective(Path(args.effective)) if args.effective else None
    scenario = [] if Path(args.scenario) == DEFAULT_SCENARIO else [str(args.scenario)]
    command = " ".join(["flexfusion study identify", *scenario, "--out", str(args.out)]
                       + ([f"--include {args.include}"] if args.include else [])
                       + ([f"--effective {args.effective}"] if args.effective else [])
                       + [f"--working-point {p}" for p in args.working_point or ()]
                       + [f"--{k.replace('_', '-')} {getattr(args, k)}" for k in ("amplitude", "stop_time")
                          if getattr(args, k) is not None]
                       + ([f"--prefilter {args.prefilter:g}"] if args.prefilter != ident.PRACTICE.prefilter else [])
                       + (["--no-acc-calibration"] if args.no_acc_calibration else [])
                       + (["--noise-free"] if args.noise_free else [])
                       + [f"--set {o}" for o in args.set or ()])
    with open_executor(args.workers, args.scheduler) as ex:
        rep = identify(args.scenario, out, ex, points=points, overrides=overrides, amplitude=args.amplitude,
                       max_nfev=args.max_nfev, criterion=args.criterion,
                       include=Path(args.include) if args.include else None,
                       command=command, progress=not args.no_progress, effective=effective,
                       noise_free=args.noise_free)
    print(_summary(rep))
    print(_coverage_line(rep["uncertainty"]["coverage"]))
    print(f"s^2 = {rep['fit']['s2']:.3g}; {rep['fit']['nfev']} residual evaluations; "
          f"{rep['wall_time']:.1f} s; plant: {rep['plant']['note']}")
    print(f"written: {out / 'identify.json'}, {args.include or out / (SET_NAME + '.toml')}")
    return 0


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


def parse_point(text: str) -> tuple[float, float]:
    """``X,Z`` -> ``(X, Z)``."""
    try:
        x, z = (float(v) for v in text.split(","))
    except ValueError:
        raise StudyError(f"--working-point {text!r}: expected X,Z in metres, e.g. 0.7,1.3") from None
    return x, z


def register(subparsers: Any) -> None:
    """Add ``flexfusion study identify``."""
    p = subparsers.add_parser("identify", help="identify the estimators' robot model on the plant "
                              "(closed-loop output error; writes identify.json and an include file)",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("scenario", nargs="?", default=str(DEFAULT_SCENARIO),
                   help="experiment scenario (default: scenarios/identify_experiment.toml)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--working-point", action="append", metavar="X,Z",
                   help="tool position of an experiment (repeatable; default: three points)")
    p.add_argument("--amplitude", type=float, default=None, help="multisine RMS per joint, N m "
                   "(default: the scenario's)")
    p.add_argument("--stop-time", type=float, default=None, help="length of each experiment (s)")
    p.add_argument("--max-nfev", type=_positive, default=60, help="residual evaluations of the optimiser "
                   "(default 60: the realistic plant took 37 with delta and w_c fitted)")
    p.add_argument("--prefilter", type=float, default=ident.PRACTICE.prefilter, metavar="HZ",
                   help="low-pass cut-off of the output-error prefilter, Hz (0: none; default "
                   f"{ident.PRACTICE.prefilter:g}, below the link bending mode)")
    p.add_argument("--noise-free", action="store_true",
                   help="run the experiments with the sensors' noise, quantisation and bias walk off (whitened "
                   "at the data-sheet levels): the effective values, for --effective (run it long: --stop-time)")
    p.add_argument("--no-acc-calibration", action="store_true",
                   help="do not estimate the accelerometer's scale, mounting and bias (assume the nominal ones)")
    p.add_argument("--effective", default=None, metavar="IDENTIFY_JSON",
                   help="identify.json of a noise-free (long) identification on the same plant: its fitted "
                   "values are the effective values reported beside the true ones, with their coverage")
    p.add_argument("--include", default=None, metavar="FILE",
                   help="include file to write (default DIR/identified_robot.toml)")
    p.add_argument("--set", action="append", metavar="COMP.PARAM=VALUE",
                   help="override in every experiment, e.g. plant.ideal=true (repeatable)")
    add_executor_arguments(p)
    p.set_defaults(func=main)


__all__ = ["identify", "run_experiments", "experiment_overrides", "recorded", "report", "write_include",
           "load_effective",
           "plant_truth", "noise_levels", "WORKING_POINTS", "register"]
