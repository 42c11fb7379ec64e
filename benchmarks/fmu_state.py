"""FMU state: get, set, serialise and deserialise each FMU's complete state (the FMI calls
``fmi2GetFMUstate``, ``fmi2SetFMUstate``, ``fmi2SerializeFMUstate``,
``fmi2DeSerializeFMUstate`` below the native layer), after 200 steps of 1 ms from the defaults.

Forks save (get + serialise) and start from (deserialise + set) a state; the tuning and batched
engines get and set states in memory. Prints, per FMU, the median time of each call over
``--repeat`` calls and the serialised size.

    .venv/bin/python benchmarks/fmu_state.py [--repeat 50]
"""
from __future__ import annotations

import argparse
import importlib
import inspect
import statistics
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def slaves() -> list:
    """One started instance of every FMU class of the working tree, stepped 200 times."""
    from fmus.common.fmi import FlexFusionSlave
    found = []
    for f in sorted((REPO / "fmus").glob("*/*_fmu.py")):
        mod = importlib.import_module(".".join(f.relative_to(REPO).with_suffix("").parts))
        for name, cls in vars(mod).items():
            if inspect.isclass(cls) and issubclass(cls, FlexFusionSlave) and cls.__module__ == mod.__name__ \
                    and not name.startswith("_"):
                s = cls(instance_name=name, resources=str(REPO))
                s.setup_experiment(0.0, None, None)
                s.enter_initialization_mode()
                s.exit_initialization_mode()
                for k in range(200):
                    s.do_step(k * 1e-3, 1e-3)
                found.append(s)
    return found


def median_ms(call, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=50)
    args = ap.parse_args()
    total = [0.0] * 4
    print(f"{'FMU':22s} {'get':>8s} {'set':>8s} {'serialise':>10s} {'deserialise':>12s} {'bytes':>9s}  (ms, median)")
    for s in slaves():
        state = s._get_fmu_state()
        data = s._fmu_state_to_bytes(state)
        s._fmu_state_from_bytes(data)                   # first-call costs (an identity hash) out
        row = [median_ms(s._get_fmu_state, args.repeat), median_ms(lambda: s._set_fmu_state(state), args.repeat),
               median_ms(lambda: s._fmu_state_to_bytes(state), args.repeat),
               median_ms(lambda: s._fmu_state_from_bytes(data), args.repeat)]
        total = [a + b for a, b in zip(total, row)]
        print(f"{type(s).__name__:22s} {row[0]:8.3f} {row[1]:8.3f} {row[2]:10.3f} {row[3]:12.3f} {len(data):9d}")
    print(f"{'all':22s} {total[0]:8.3f} {total[1]:8.3f} {total[2]:10.3f} {total[3]:12.3f}")


if __name__ == "__main__":
    main()
