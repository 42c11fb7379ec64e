"""The schedule of a co-simulation: what is stepped when, in which order, from which values.

Computed once from a loaded scenario (its components, connections, delays and the
modelDescriptions' output dependencies) by :meth:`Schedule.of`, and followed by every engine
that steps a scenario: the master's C loop (``orchestration/cosim_loop.c``, which gets the
schedule's tables through :class:`orchestration.cloop.CLoop`), its Python reference
(:func:`orchestration.master._python_steps`) and the batched study engine
(:mod:`orchestration.batched`). A change of the stepping rule is an edit here.

The rules:

* **Order** (Gauss–Seidel): the components in topological order of the connection graph (ties:
  scenario order), each one's inputs set from the freshest outputs of its producers. A cycle
  is broken at one edge, preferably one the scenario declares in ``delays`` (an intended
  one-step delay), else one whose target input has no direct feedthrough to an output; the
  consumer on that edge reads the producer's previous value (Jacobi); an undeclared one gives
  a note (:attr:`Schedule.notes`, the master's ``CouplingWarning``). A cycle of
  direct-feedthrough dependencies only is an algebraic loop and is refused.
* **Rates**: a component of communication step ``ratio * h`` is stepped at the base steps ``k``
  with ``k % ratio == 0`` (``doStep(k h, ratio h)``) and its outputs are held in between; no
  step passes the stop time: where the next step would, the component is no longer stepped.
  :attr:`Schedule.due` holds the components stepped at each base step, one row per base step
  of the periodic pattern (the least common multiple of the ratios) and, after it, one row per
  base step of the tail (the last base steps, where a step would pass the stop time);
  :meth:`Schedule.row` says which row base step ``k`` uses.
* **Gathers**: each component's connected inputs (:attr:`Schedule.inputs`), set just before its
  step, read from one buffer of every output read (:attr:`Schedule.reads`: per component in
  order, its connected outputs first, then those only recorded; :attr:`Schedule.offsets`).
* **Initialisation** (:attr:`Schedule.initialisation`, :meth:`Schedule.initialise`): in order,
  each component gets its inputs from its producers' initial outputs, leaves initialisation
  mode, and its outputs are read; where an edge is broken, its consumer saw its producer's
  start value, so one more pass in order (step mode, before the first step: inputs set,
  outputs read) gives every input its initial value.
"""
from __future__ import annotations

import heapq
import math
import sys
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from .scenario import Component, Scenario, ScenarioError


@dataclass(frozen=True)
class Schedule:
    """The schedule of one scenario (the module docstring); components are named by their index
    in :attr:`order` where a loop reads the schedule (``due``, ``gathers``).

    Attributes
    ----------
    order
        The components in Gauss–Seidel order.
    broken, broken_text
        The broken cycle edges ``(producer, consumer)`` and the connections on them.
    notes
        A coupling warning per broken connection not declared in ``delays``.
    inputs
        Per component, its connected inputs ``(input scalar, producer, producer scalar)`` in the
        order they are set.
    reads
        Per component, the output scalars read from it: connected first, then recorded ones.
    connected
        Per component, how many of its ``reads`` are connected (the rest only recorded).
    starts, offsets, size
        The buffer of every read output: component ``n``'s first slot, the slot of
        ``(n, scalar)``, and the number of slots.
    gathers
        Per component index, the buffer slots its inputs are set from, in ``inputs`` order.
    ratio, step
        Per component index, its communication step in base steps and in seconds.
    due
        Rows of component indices stepped at a base step, in order (:meth:`row` picks one).
    period, tail_start
        Rows ``0 .. period-1`` repeat for base steps ``k < tail_start``; from ``tail_start``
        on, base step ``k`` has its own row ``period + k - tail_start``.
    initialisation
        The initialisation passes in order: True leaves initialisation mode (the first),
        False is the extra pass of a broken edge.
    n_steps, base_step
        The run's base steps and the base step ``h`` (s).
    """

    order: tuple[str, ...]
    broken: tuple[tuple[str, str], ...]
    broken_text: tuple[str, ...]
    notes: tuple[str, ...]
    inputs: dict[str, list[tuple[str, str, str]]]
    reads: dict[str, list[str]]
    connected: dict[str, int]
    starts: dict[str, int]
    offsets: dict[tuple[str, str], int]
    size: int
    gathers: tuple[tuple[int, ...], ...]
    ratio: tuple[int, ...]
    step: tuple[float, ...]
    due: tuple[tuple[int, ...], ...]
    period: int
    tail_start: int
    initialisation: tuple[bool, ...]
    n_steps: int
    base_step: float

    @classmethod
    def of(cls, scenario: Scenario, recorded: Sequence[str] | None = None) -> "Schedule":
        """The schedule of ``scenario``, reading the outputs ``recorded`` (``comp.scalar``;
        default: the scenario's record columns) besides the connected ones.

        Raises
        ------
        ScenarioError
            An algebraic loop; a connection declared in ``delays`` where no cycle is broken.
        """
        order, broken, broken_text = _order(scenario)
        comps = scenario.components
        inputs: dict[str, list[tuple[str, str, str]]] = {n: [] for n in comps}
        reads: dict[str, list[str]] = {n: [] for n in comps}
        for c in scenario.connections:
            for s, d in c.pairs:
                inputs[c.dst].append((d, c.src, s))
                if s not in reads[c.src]:
                    reads[c.src].append(s)
        connected = {n: len(reads[n]) for n in comps}
        for col in (scenario.record_columns() if recorded is None else recorded):
            cname, var = col.split(".", 1)
            if var not in reads[cname]:
                reads[cname].append(var)
        starts: dict[str, int] = {}
        offsets: dict[tuple[str, str], int] = {}
        for n in order:
            starts[n] = len(offsets)
            for var in reads[n]:
                offsets[(n, var)] = len(offsets)
        ratio = tuple(comps[n].ratio for n in order)
        due, period, tail_start = _due(ratio, scenario.n_steps)
        notes = tuple(f"{scenario.name}: connection '{text}' is in a cycle; it uses the previous step's "
                      "value (Jacobi)" for text in broken_text if text not in scenario.delays)
        return cls(order=tuple(order), broken=tuple(broken), broken_text=tuple(broken_text), notes=notes,
                   inputs=inputs, reads=reads, connected=connected, starts=starts, offsets=offsets,
                   size=len(offsets),
                   gathers=tuple(tuple(offsets[(s, v)] for _, s, v in inputs[n]) for n in order),
                   ratio=ratio, step=tuple(comps[n].step for n in order), due=due, period=period,
                   tail_start=tail_start, initialisation=(True, False) if broken else (True,),
                   n_steps=scenario.n_steps, base_step=scenario.base_step)

    def row(self, k: int) -> int:
        """The row of :attr:`due` that base step ``k`` follows (``cosim_loop.c`` computes the
        same)."""
        return k % self.period if k < self.tail_start else self.period + k - self.tail_start

    def due_at(self, k: int) -> tuple[int, ...]:
        """The components (indices into :attr:`order`) stepped at base step ``k``, in order."""
        return self.due[self.row(k)]

    def names(self, row: Sequence[int]) -> list[str]:
        """The component names of a row of indices."""
        return [self.order[i] for i in row]

    def initialise(self, exchange: Callable[[int, bool], Any]) -> None:
        """Initialisation: ``exchange(i, leave)`` for every component index ``i`` in order, per
        pass of :attr:`initialisation`. The engine's ``exchange`` sets the component's inputs
        (if it has any) from the freshest outputs, leaves initialisation mode if ``leave``, and
        reads its outputs."""
        for leave in self.initialisation:
            for i in range(len(self.order)):
                exchange(i, leave)


def _due(ratio: Sequence[int], n_steps: int) -> tuple[tuple[tuple[int, ...], ...], int, int]:
    """``(due rows, period, tail_start)`` of :class:`Schedule` for components (in order) of
    these ratios: stepped at base step ``k`` when ``k % ratio == 0`` and the step ends by the
    stop time (``k + ratio <= n_steps``). Before ``tail_start`` every due step ends by then, so
    one period of the pattern serves; the tail (fewer base steps than the largest ratio) is
    written out."""
    def stepped(k: int) -> tuple[int, ...]:
        return tuple(i for i, r in enumerate(ratio) if k % r == 0 and k + r <= n_steps)

    period = math.lcm(*ratio) if ratio else 1
    tail_start = max(0, n_steps - max(ratio, default=1) + 1)
    return (tuple(tuple(i for i, r in enumerate(ratio) if j % r == 0) for j in range(period))
            + tuple(stepped(k) for k in range(tail_start, n_steps)), period, tail_start)


# ---------------------------------------------------------------------------------------------
# the order
# ---------------------------------------------------------------------------------------------
def _feedthrough(comp: Component, input_scalar: str) -> bool:
    return any(input_scalar in (v.depends_on or ()) for v in comp.variables.values()
               if v.causality == "output")


def find_algebraic_loop(scenario: Scenario) -> list[str] | None:
    """A cycle of direct feedthrough through the connections (as ``comp.var`` names), or None."""
    succ: dict[str, list[str]] = {}
    for c in scenario.connections:
        for s, d in c.pairs:
            succ.setdefault(f"{c.src}.{s}", []).append(f"{c.dst}.{d}")
    for comp in scenario.components.values():
        for name, v in comp.variables.items():
            if v.causality == "output":
                for inp in v.depends_on or ():
                    succ.setdefault(f"{comp.name}.{inp}", []).append(f"{comp.name}.{name}")
    color: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        color[n] = 1
        stack.append(n)
        for m in succ.get(n, ()):
            if color.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if color.get(m) is None:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        color[n] = 2
        return None

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(succ) + 100))
    try:
        for n in sorted(succ):
            if color.get(n) is None:
                found = visit(n)
                if found:
                    return found
    finally:
        sys.setrecursionlimit(limit)
    return None


def _order(scenario: Scenario) -> tuple[list[str], list[tuple[str, str]], list[str]]:
    """``(order, broken edges, their connections)``: the Gauss–Seidel order of the components
    (ties: scenario order), cycles broken (the module docstring).

    Raises
    ------
    ScenarioError
        On an algebraic loop; a connection declared in ``delays`` where no cycle is broken (it
        would read the fresh value).
    """
    loop = find_algebraic_loop(scenario)
    if loop:
        where = f"{scenario.path}: " if scenario.path else ""
        raise ScenarioError(f"{where}algebraic loop of direct feedthrough: " + " -> ".join(loop)
                            + " (break it with a component that has no direct feedthrough)")
    names = list(scenario.components)
    rank = {n: i for i, n in enumerate(names)}
    edges: dict[tuple[str, str], list[Any]] = {}
    for c in scenario.connections:
        edges.setdefault((c.src, c.dst), []).append(c)
    active = set(edges)
    broken: list[tuple[str, str]] = []
    broken_text: list[str] = []
    while True:
        order = _kahn(names, active, rank)
        if len(order) == len(names):
            unbroken = sorted(set(scenario.delays) - set(broken_text))
            if unbroken:
                raise ScenarioError(f"{scenario.path or scenario.name}: delays: "
                                    f"{', '.join(repr(d) for d in unbroken)} is where no cycle is "
                                    "broken: it reads the fresh value, not a delayed one")
            return order, broken, broken_text
        placed = set(order)
        rest = [n for n in names if n not in placed]
        cycle = _find_cycle(rest, active, rank)

        # prefer a declared delay, then an edge whose consumer inputs have no direct feedthrough
        def cost(e: tuple[str, str]) -> tuple[int, int, int, int]:
            ft = any(_feedthrough(scenario.components[e[1]], d) for c in edges[e] for _, d in c.pairs)
            declared = all(str(c) in scenario.delays for c in edges[e])
            return (0 if declared else 1, 1 if ft else 0, rank[e[1]], rank[e[0]])
        edge = min(cycle, key=cost)
        active.discard(edge)
        broken.append(edge)
        broken_text += [str(c) for c in edges[edge]]


def _kahn(names: list[str], edges: set[tuple[str, str]], rank: dict[str, int]) -> list[str]:
    """Kahn's topological sort, the ready component of lowest rank first; O((V + E) log V)."""
    indeg = {n: 0 for n in names}
    succ: dict[str, list[str]] = {n: [] for n in names}
    for (s, d) in edges:
        indeg[d] += 1
        succ[s].append(d)
    ready = [(rank[n], n) for n in names if indeg[n] == 0]
    heapq.heapify(ready)
    order: list[str] = []
    while ready:
        _, n = heapq.heappop(ready)
        order.append(n)
        for d in succ[n]:
            indeg[d] -= 1
            if indeg[d] == 0:
                heapq.heappush(ready, (rank[d], d))
    return order


def _find_cycle(nodes: list[str], edges: set[tuple[str, str]], rank: dict[str, int]) -> list[tuple[str, str]]:
    """Edges of one cycle among ``nodes``, the ones Kahn's sort left.

    Each of them has a predecessor among them (else the sort would have taken it), so a walk
    backwards through predecessors (the one of lowest rank) must repeat a node; the repeated
    part is a cycle. (A forward walk can end at a node that is only downstream of a cycle.)
    """
    node_set = set(nodes)
    pred: dict[str, str] = {}
    for (s, d) in edges:
        if s in node_set and d in node_set and (d not in pred or rank[s] < rank[pred[d]]):
            pred[d] = s
    path = [nodes[0]]
    seen = {nodes[0]: 0}
    while True:
        n = pred[path[-1]]
        if n in seen:
            cyc = (path[seen[n]:] + [n])[::-1]
            return list(zip(cyc[:-1], cyc[1:]))
        seen[n] = len(path)
        path.append(n)


__all__ = ["Schedule", "find_algebraic_loop"]
