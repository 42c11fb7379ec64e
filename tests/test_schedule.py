"""The co-simulation's schedule (orchestration/schedule.py) on a small multi-rate scenario with a
broken cycle, against what it must be, worked out by hand below; and the master following it."""
from __future__ import annotations

import warnings

import pytest

from orchestration import CouplingWarning, run
from orchestration.scenario import ScenarioError, load_scenario
from orchestration.schedule import Schedule
from toys import write

pytestmark = pytest.mark.usefixtures("toy_fmus")

# a and b: mass-springs coupled both ways (a cycle, no feedthrough either way); src -> g (a gain,
# direct feedthrough). Steps in base steps (h = 0.01 s): a 1, src 2, g 5, b 3. The stop time
# 0.97 s (97 base steps) is divided by a's step only.
SCENARIO = """
connections = ["src.y -> g.u", "a.x -> b.x_other", "b.x -> a.x_other"]
[scenario]
name = "ring"
stop_time = 0.97
base_step = 0.01
[components.a]
fmu = "MassSpring"
parameters = { x0 = 1.0 }
[components.src]
fmu = "Source"
step = 0.02
[components.g]
fmu = "Gain"
step = 0.05
[components.b]
fmu = "MassSpring"
step = 0.03
[record]
variables = ["a.x", "b.x", "g.y", "src.n"]
interval = 0.01
"""


def test_order_broken_edge_gathers_and_initialisation_of_a_small_scenario(tmp_path):
    """By hand: Kahn's sort places src, then g; a and b wait on each other. Both edges of the
    cycle end in an input without feedthrough, so the tie goes to the consumer listed first: the
    edge b -> a is broken (a reads b's previous x). Sorting again with it removed, the ready
    component listed first goes first: a, src, g, b.

    The buffer holds per component in that order what is read from it, connected outputs first
    (in connection order), then the recorded ones: a.x 0, src.y 1, src.n 2, g.y 3, b.x 4. Each
    input is gathered from its producer's slot: a.x_other from 4 (b.x), g.u from 1 (src.y),
    b.x_other from 0 (a.x). A broken edge adds the second initialisation pass."""
    p = Schedule.of(load_scenario(write(tmp_path, SCENARIO)))
    assert p.order == ("a", "src", "g", "b")
    assert p.broken == (("b", "a"),) and p.broken_text == ("b.x -> a.x_other",)
    assert p.notes == ("ring: connection 'b.x -> a.x_other' is in a cycle; it uses the previous step's "
                       "value (Jacobi)",)
    assert p.inputs == {"a": [("x_other", "b", "x")], "src": [], "g": [("u", "src", "y")],
                        "b": [("x_other", "a", "x")]}
    assert p.reads == {"a": ["x"], "src": ["y", "n"], "g": ["y"], "b": ["x"]}
    assert p.connected == {"a": 1, "src": 1, "g": 0, "b": 1}
    assert p.offsets == {("a", "x"): 0, ("src", "y"): 1, ("src", "n"): 2, ("g", "y"): 3, ("b", "x"): 4}
    assert p.starts == {"a": 0, "src": 1, "g": 3, "b": 4} and p.size == 5
    assert p.gathers == ((4,), (), (1,), (0,))
    assert p.ratio == (1, 2, 5, 3) and p.step == (0.01, 0.02, 0.05, 0.03)
    assert p.initialisation == (True, False)
    calls = []
    p.initialise(lambda i, leave: calls.append((p.order[i], leave)))
    assert calls == [("a", True), ("src", True), ("g", True), ("b", True),
                     ("a", False), ("src", False), ("g", False), ("b", False)]


def test_rates_and_the_stop_time_of_a_small_scenario(tmp_path):
    """By hand: the pattern repeats every lcm(1, 2, 5, 3) = 30 base steps; a component steps at
    the base steps its step divides, so at 0: all; 6: a, src, b; 10: a, src, g; 15: a, g, b;
    7: a alone. No step may end after base step 97: the largest step, g's 5, could pass it
    from base step 93 on, so the tail is written out from there: 93: a, b (ends at 96);
    94: a, src (ends at 96); 95: a (g would end at 100); 96: a (src at 98, b at 99 would pass).
    Over the run: a steps 97 times, src at 0, 2, ..., 94 (48), g at 0, 5, ..., 90 (19),
    b at 0, 3, ..., 93 (32)."""
    p = Schedule.of(load_scenario(write(tmp_path, SCENARIO)))
    assert (p.period, p.tail_start, p.n_steps) == (30, 93, 97)
    assert len(p.due) == 30 + 4
    at = {k: p.names(p.due_at(k)) for k in (0, 6, 7, 10, 15, 30, 36, 93, 94, 95, 96)}
    assert at == {0: ["a", "src", "g", "b"], 6: ["a", "src", "b"], 7: ["a"], 10: ["a", "src", "g"],
                  15: ["a", "g", "b"], 30: ["a", "src", "g", "b"], 36: ["a", "src", "b"],
                  93: ["a", "b"], 94: ["a", "src"], 95: ["a"], 96: ["a"]}
    stepped: dict[str, list[int]] = {n: [] for n in p.order}
    for k in range(p.n_steps):
        for n in p.names(p.due_at(k)):
            stepped[n].append(k)
    assert {n: (len(ks), ks[-1]) for n, ks in stepped.items()} == {"a": (97, 96), "src": (48, 94),
                                                                  "g": (19, 90), "b": (32, 93)}


def test_the_master_steps_as_the_schedule_says(tmp_path):
    """src counts its steps (src.n): 47 after base step 93, 48 after its step at 94, and still
    48 in the last row (after base step 96, where its step would pass the stop time); g holds
    src.y from its last step at base step 90 (src stepped just before it: y = 0.90 + 0.02,
    times the gain's default 1, offset 0); a step at 95 would read 0.96."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CouplingWarning)
        r = run(write(tmp_path, SCENARIO), out_dir=tmp_path / "o")
    k = r.time.round(2)
    assert k[-1] == 0.97 and list(r["src.n"][k >= 0.94]) == [47, 48, 48, 48]
    assert r["g.y"][-1] == pytest.approx(0.92, abs=1e-12)


def test_a_declared_delay_gives_no_note_and_a_scenario_without_cycle_one_pass(tmp_path):
    declared = Schedule.of(load_scenario(write(tmp_path, SCENARIO.replace(
        "[scenario]", 'delays = ["b.x -> a.x_other"]\n[scenario]'))))
    assert declared.broken == (("b", "a"),) and declared.notes == () and declared.initialisation == (True, False)
    acyclic = Schedule.of(load_scenario(write(tmp_path, SCENARIO.replace(', "b.x -> a.x_other"', ""))))
    assert acyclic.broken == () and acyclic.initialisation == (True,)
    assert acyclic.order == ("a", "src", "g", "b")
    with pytest.raises(ScenarioError, match="is where no cycle is broken"):
        Schedule.of(load_scenario(write(tmp_path, SCENARIO.replace(
            "[scenario]", 'delays = ["src.y -> g.u"]\n[scenario]'))))


def test_the_outputs_read_are_the_connected_ones_then_those_asked_for(tmp_path):
    """The batched engine asks for its own recorded outputs instead of the scenario's."""
    p = Schedule.of(load_scenario(write(tmp_path, SCENARIO)), ["src.t_s", "src.y", "g.yv[2]"])
    assert p.reads == {"a": ["x"], "src": ["y", "t_s"], "g": ["yv[2]"], "b": ["x"]}
    assert p.connected == {"a": 1, "src": 1, "g": 0, "b": 1}
