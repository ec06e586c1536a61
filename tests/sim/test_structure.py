"""The simulator's modules import each other in one direction only.

The two truth models share the speed control and the truth trace (``control``, ``trace``), the two recording
writers share the bus identities and the GNSS receiver's output (``frames``, ``gnss_receiver``): a module that
both need sits below both, so none has to reach back into the other inside a function.
"""

from __future__ import annotations

import ast
from pathlib import Path

import tractionecu.sim as sim

SIM_DIR = Path(sim.__file__).parent


def _sim_imports() -> dict[str, set[str]]:
    """Module name -> the sibling ``tractionecu.sim`` modules it imports anywhere (module or function level)."""
    names = {p.stem for p in SIM_DIR.glob("*.py")}
    graph: dict[str, set[str]] = {}
    for path in SIM_DIR.glob("*.py"):
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level == 1 and node.module:                      # from .x import ...
                deps.add(node.module.split(".")[0])
            elif node.level == 1:                                    # from . import x
                deps.update(a.name for a in node.names)
            elif node.level == 0 and (node.module or "").startswith("tractionecu.sim."):
                deps.add(node.module.split(".")[2])
        graph[path.stem] = {d for d in deps if d in names and d != path.stem}
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``graph`` as a list of modules (first repeated last), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state and (found := visit(d)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_the_graph_is_read() -> None:
    g = _sim_imports()
    assert {"control", "trace"} <= g["simulator"] and {"control", "trace"} <= g["physical"]
    assert {"frames", "gnss_receiver", "physwriter"} <= g["writer"]
    assert {"frames", "gnss_receiver", "physical"} <= g["physwriter"]


def test_no_import_cycle_inside_the_simulator() -> None:
    assert _cycle(_sim_imports()) is None, " -> ".join(_cycle(_sim_imports()) or [])


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_the_shared_pieces_keep_their_old_names() -> None:
    from tractionecu.sim import control, frames, gnss_receiver, physical, physwriter, simulator, trace, writer

    assert simulator.TruthTrace is trace.TruthTrace is physical.TruthTrace
    assert simulator.Shuttle is control.Shuttle is physical.Shuttle
    assert simulator.ControllerSpec is control.ControllerSpec and simulator.V_STANDSTILL == control.V_STANDSTILL
    assert (writer.FORWARD, writer.REVERSE, writer.NAV_SA) == (frames.FORWARD, frames.REVERSE, frames.NAV_SA)
    assert writer.gnss_sentences is gnss_receiver.gnss_sentences is physwriter.gnss_sentences
    assert writer.write_physical_recording is physwriter.write_physical_recording
