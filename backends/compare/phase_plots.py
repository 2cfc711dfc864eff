"""Example trajectories in the state space: the picture a control engineer reads first.

:func:`choose_projection` picks, from the spec alone, the state coordinates that show the task
(a pair, or a small grid of pairs); :func:`scene` projects the goal, the unsafe regions and the
initial box on them; :func:`example` gathers a few episodes of a policy and of the oracle's
replayed action sequences from the same initial states; :func:`state_space` draws them (PNG bytes,
matplotlib Agg). :func:`plot_run` is ``asapc eval --plot``.
"""

from __future__ import annotations

import io
import itertools
import math
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Optional, Sequence, Union

import numpy as np

from asap_dsl.expr import names_in
from asap_dsl.model import RegionModel, SystemModel, TaskModel
from asap_dsl.sampling import init_box
from asap_dsl.stl import ir

from .report import reference

__all__ = ["Example", "Projection", "Scene", "Shape", "choose_projection", "example", "plot_run", "scene",
           "state_space"]

#: A coordinate leads when its offset is at least this share of the largest (bicycle: v's 0.07
#: against x's and y's 0.10 of the state space does not: its plot is x–y).
LEAD = 0.75
#: At most this many leading coordinates make the grid (three pairs).
GRID = 3
TIME = None  # the horizontal axis of a one-state system: the step
DPI = 100
PANEL = (4.8, 4.4)  # inches per panel
MIN_WIDTH = 9.6     # inches: at least 960 px wide, readable beside the report's other figures
LEGEND = 0.75       # inches of the legend below the panels (two rows)
LINE = 0.19         # inches per line of the caption under it (what is drawn, why these coordinates)
CAPTION_CHARS = 13  # characters of the caption per inch of width, at its 9 points


@dataclass(frozen=True)
class Projection:
    """Pairs of state indices (horizontal, vertical; ``None`` horizontal: the step) and why."""

    pairs: tuple[tuple[Optional[int], int], ...]
    why: str


def _widths(system: SystemModel) -> np.ndarray:
    w = system.state_high - system.state_low
    return np.where(np.isfinite(w) & (w > 0), w, 1.0)


def _centre(region: RegionModel, system: SystemModel) -> dict[int, float]:
    """The region's centre on each state coordinate it constrains (a box clipped to the state space)."""
    index = {s.name: s.index for s in system.states}
    out = {}
    for j, c in enumerate(region.coords):
        if c not in index:
            continue  # a let: no state axis to measure along
        k = index[c]
        if region.kind == "ball":
            out[k] = float(region.centre[j])
        else:
            lo = max(float(region.low[j]), float(system.state_low[k]))
            hi = min(float(region.high[j]), float(system.state_high[k]))
            out[k] = (lo + hi) / 2 if math.isfinite(lo + hi) else (lo if math.isfinite(lo) else hi)
    return out


def _offsets(names: Sequence[str], regions: Mapping[str, RegionModel], system: SystemModel,
             mid: np.ndarray) -> np.ndarray:
    """Per state coordinate: the largest offset of these regions' centres from the initial box's
    centre, as a share of the coordinate's state-space width."""
    out = np.zeros(system.n_state)
    for name in names:
        if name in regions:
            for k, c in _centre(regions[name], system).items():
                if math.isfinite(c):
                    out[k] = max(out[k], abs(c - mid[k]))
    return out / _widths(system)


def _partners(system: SystemModel, k: int) -> list[int]:
    """The other states the equation of state ``k`` reads (lets followed): ``theta' = omega``
    makes omega theta's partner, the phase plane. None for a black box."""
    if system.kind == "simulator" or not system.equations:
        return []
    index = {s.name: s.index for s in system.states}
    found, seen, stack = [], set(), [system.equations[k]]
    while stack:
        for n in names_in(stack.pop()):
            if n.id in seen:
                continue
            seen.add(n.id)
            if n.id in index and index[n.id] != k:
                found.append(index[n.id])
            elif n.id in system.lets:
                stack.append(system.lets[n.id])
    return found


def choose_projection(system: SystemModel, task: TaskModel, regions: Mapping[str, RegionModel]) -> Projection:
    """The state coordinates that show ``task``, from the spec alone.

    Each coordinate is scored by how far the goal's centre lies from the initial box's centre
    along it, as a share of its state-space width (where the goal sits at the box's centre, by the
    box's own half-width: the spread is then the distance to cover). Two or three coordinates
    within :data:`LEAD` of the largest score are the pair, or the grid of their pairs. A single
    leader is paired with the coordinate the unsafe regions are offset along (they are what the
    path has to go around), else with a state its equation reads (``theta' = omega``: the phase
    plane), else with the next best score. A one-state system is drawn against the step.
    """
    n = system.n_state
    names = system.state_names
    if n == 1:
        return Projection(((TIME, 0),), f"{names[0]} against the step (a one-state system)")
    low, high = init_box(system, task.init_box)
    mid = (low + high) / 2
    score = _offsets(task.asap_regions, regions, system, mid)
    basis = "the goal's offset from the initial box's centre"
    if score.max() <= 1e-12:
        score = (high - low) / 2 / _widths(system)
        basis = "the initial box's spread (the goal sits at its centre)"
    order = sorted(range(n), key=lambda k: (-score[k], k))
    top = score[order[0]]
    leaders = [k for k in order if score[k] >= LEAD * top - 1e-12][:GRID]
    if len(leaders) >= 2:
        pairs = tuple(itertools.combinations(sorted(leaders), 2))
        return Projection(pairs, f"{', '.join(names[k] for k in sorted(leaders))} carry {basis}")
    lead = leaders[0]
    unsafe = _offsets(task.avoid_regions, regions, system, mid)
    unsafe[lead] = 0.0
    if unsafe.max() > 1e-12:
        other = int(np.argmax(unsafe))
        why = f"{names[lead]} carries {basis}; the unsafe region is offset along {names[other]}"
    elif _partners(system, lead):
        other = _partners(system, lead)[0]
        why = f"{names[lead]} carries {basis}; its equation reads {names[other]} (the phase plane)"
    else:
        other = order[1]
        why = f"{names[lead]} carries {basis}; {names[other]} comes next"
    return Projection(((lead, other),), why)


# ---------------------------------------------------------------------------------- the scene
@dataclass(frozen=True)
class Shape:
    """A region's projection on one pair: a disc (``centre``, ``radius``) or a rectangle
    (``x`` and ``y`` intervals, infinite where the region does not constrain that axis)."""

    role: str   # "goal" | "unsafe"
    name: str
    kind: str   # "disc" | "rect"
    centre: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0
    x: tuple[float, float] = (-math.inf, math.inf)
    y: tuple[float, float] = (-math.inf, math.inf)


@dataclass(frozen=True)
class Scene:
    """What every panel of a (spec, task) draws besides the paths: plain data."""

    names: tuple[str, ...]
    low: tuple[float, ...]           # the state space
    high: tuple[float, ...]
    init_low: tuple[float, ...]
    init_high: tuple[float, ...]
    steps: int                       # the deadline (the time axis of a one-state system)
    projection: Projection
    shapes: tuple[tuple[Shape, ...], ...]  # per pair
    notes: tuple[str, ...] = ()


def _project(region: RegionModel, role: str, pair, system: SystemModel) -> Optional[Shape]:
    """The region's projection on ``pair``; None where it constrains neither axis."""
    at = {c: j for j, c in enumerate(region.coords)}
    names = [None if k is TIME else system.state_names[k] for k in pair]
    js = [at.get(nm) if nm is not None else None for nm in names]
    if js[0] is None and js[1] is None:
        return None
    if region.kind == "ball" and None not in js:
        return Shape(role, region.name, "disc", (float(region.centre[js[0]]), float(region.centre[js[1]])),
                     float(region.radius))
    sides = []
    for j in js:
        if j is None:
            sides.append((-math.inf, math.inf))
        elif region.kind == "ball":
            c = float(region.centre[j])
            sides.append((c - region.radius, c + region.radius))
        else:
            sides.append((float(region.low[j]), float(region.high[j])))
    return Shape(role, region.name, "rect", x=sides[0], y=sides[1])


def _formula_note(what: str, formula: Optional[ir.Formula], drawn: Sequence[str]) -> Optional[str]:
    if formula is None or (isinstance(formula, ir.Atom) and formula.region is not None):
        return None
    return (f"{what} is `{ir.to_text(formula)}`: drawn are only the regions it asks to be in "
            f"({', '.join(drawn) or 'none'}), not how they combine")


def scene(system: SystemModel, task: TaskModel, regions: Mapping[str, RegionModel]) -> Scene:
    """The projection of ``task`` (:func:`choose_projection`) and its regions drawn on it."""
    proj = choose_projection(system, task, regions)
    states = set(system.state_names)
    notes = [n for n in (_formula_note("asap", task.asap, task.asap_regions),
                         _formula_note("avoid", task.avoid, task.avoid_regions)) if n]
    per_pair = []
    for pair in proj.pairs:
        shapes = []
        for role, names in (("goal", task.asap_regions), ("unsafe", task.avoid_regions)):
            for name in names:
                r = regions.get(name)
                if r is None:
                    continue
                lets = [c for c in r.coords if c not in states]
                if lets:
                    note = f"{name} is over {', '.join(lets)} (not state coordinates): not drawn"
                    if note not in notes:
                        notes.append(note)
                    continue
                s = _project(r, role, pair, system)
                if s is not None:
                    shapes.append(s)
        per_pair.append(tuple(shapes))
    low, high = init_box(system, task.init_box)
    tup = lambda a: tuple(float(v) for v in a)  # noqa: E731
    return Scene(system.state_names, tup(system.state_low), tup(system.state_high), tup(low), tup(high),
                 int(task.deadline), proj, tuple(per_pair), tuple(notes))


# ---------------------------------------------------------------------------------- the paths
@dataclass
class Example:
    """A few episodes of one policy beside the oracle's from the same initial states."""

    title: str
    label: str                              # the policy's
    scene: Scene
    policy: list[np.ndarray]                # per state [steps + 1, n] up to the episode's end
    policy_reach: list[Optional[int]]       # the step asap first held (None: never)
    oracle: Optional[list[Optional[np.ndarray]]] = None  # None: no oracle; an entry None: no sequence
    oracle_reach: list[Optional[int]] = field(default_factory=list)
    missing: str = ""                       # why there is no oracle
    reference: str = "oracle"               # whose sequences: oracle, or planner (a black box's)


def _paths(res, keep: Optional[Sequence[bool]] = None) -> tuple[list, list]:
    """Each episode's states up to its reach step (the task ends there; the oracle's replay goes
    on with zeros after it), else up to its end; ``keep[i]`` False: None."""
    paths, reach = [], []
    for i in range(res.episodes):
        ok = keep is None or keep[i]
        t = int(res.t_reach[i]) if ok and np.isfinite(res.t_reach[i]) else None
        end = t if t is not None else int(res.end_step[i])
        paths.append(res.trajectories[i, : end + 1].copy() if ok else None)
        reach.append(t)
    return paths, reach


def example(prog, task: str, states: np.ndarray, controller, oracle, *, title: str, label: str,
            cached_only: bool = False) -> tuple[Example, object, Optional[object]]:
    """Roll ``controller`` and the oracle's replayed sequences (``oracle``: a cached oracle whose
    states include ``states``, or None) out from ``states``; return the :class:`Example` and both
    rollouts (recorded), the oracle's None without one. ``cached_only``: the oracle was only
    looked up, not computed (said in the title when there is none)."""
    from asap_dsl.rollout import Evaluator

    from .controllers import OracleController

    ev = Evaluator(prog, task, states)
    res = ev.run(controller, record=True)
    policy, reach = _paths(res)
    tm = prog.task(task).model
    if prog.system.kind == "simulator":
        missing = "a black box without the planner's cached sequences (`asapc oracle`)"
    else:
        missing = "no oracle cached for these states" if cached_only else "no oracle for this task"
    ex = Example(title, label, scene(prog.system, tm, prog.regions), policy, reach, missing=missing)
    ores = None
    if oracle is not None:
        ctrl = OracleController.from_cache(oracle, prog.system.n_action)
        ores = ev.run(ctrl, record=True)
        # A state without a sequence would replay zeros: no path is drawn for it.
        ex.oracle, ex.oracle_reach = _paths(ores, [p is not None for p in ctrl.plan])
        ex.reference = reference(oracle.bound)
    return ex, res, ores


# ---------------------------------------------------------------------------------- drawing
def _limits(values: list[float], lo: float, hi: float) -> tuple[float, float]:
    vals = [v for v in values if math.isfinite(v)]
    a, b = (min(vals), max(vals)) if vals else (lo, hi)
    pad = 0.08 * (b - a) if b > a else max(abs(a), 1.0) * 0.1
    a, b = a - pad, b + pad
    if math.isfinite(lo):
        a = max(a, lo)
    if math.isfinite(hi):
        b = min(b, hi)
    return (a, b) if b > a else (a - 0.5, a + 0.5)


def _coords(path: np.ndarray, k: Optional[int]) -> np.ndarray:
    return np.arange(len(path), dtype=float) if k is TIME else path[:, k]


def _panel(ax, ex: Example, p: int) -> None:
    from matplotlib.patches import Ellipse, Rectangle

    sc = ex.scene
    a, b = sc.projection.pairs[p]
    xs, ys = [], []
    for s in sc.shapes[p]:
        face = {"goal": "tab:green", "unsafe": "tab:red"}[s.role]
        if s.kind == "disc":
            # Width and height 2r in data units: the ball's shadow (and slice through the centre).
            ax.add_patch(Ellipse(s.centre, 2 * s.radius, 2 * s.radius, fc=face, ec=face, alpha=0.3, lw=1.2))
            xs += [s.centre[0] - s.radius, s.centre[0] + s.radius]
            ys += [s.centre[1] - s.radius, s.centre[1] + s.radius]
        else:
            x0, x1 = (max(s.x[0], -1e12), min(s.x[1], 1e12))
            y0, y1 = (max(s.y[0], -1e12), min(s.y[1], 1e12))
            ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fc=face, ec=face, alpha=0.3, lw=1.2))
            xs += list(s.x)
            ys += list(s.y)
    ilo = [0.0 if k is TIME else sc.init_low[k] for k in (a, b)]
    ihi = [0.0 if k is TIME else sc.init_high[k] for k in (a, b)]
    ax.add_patch(Rectangle((ilo[0], ilo[1]), ihi[0] - ilo[0], ihi[1] - ilo[1], fill=False, ec="0.45", ls=":", lw=1.2))
    xs += [ilo[0], ihi[0]]
    ys += [ilo[1], ihi[1]]
    n = len(ex.policy)
    for i, path in enumerate(ex.policy):
        colour = f"C{i % 10}"
        oracle = (ex.oracle or [None] * n)[i], (ex.oracle_reach or [None] * n)[i]
        for mine, (q, t) in ((False, oracle), (True, (path, ex.policy_reach[i]))):
            if q is None:
                continue
            u, v = _coords(q, a), _coords(q, b)
            if mine:
                ax.plot(u, v, color=colour, lw=1.8, alpha=0.75)
            else:  # on top, so that a policy following the oracle leaves its dashes visible
                ax.plot(u, v, color=colour, ls=(0, (4, 2)), lw=1.3, zorder=3)
            xs += list(u)
            ys += list(v)
            if t is not None:
                ax.plot(u[-1], v[-1], marker="*", ms=12, color=colour, mec="k", mew=0.7,
                        mfc=colour if mine else "white", zorder=5)
            elif mine:  # where the policy's episode ended without reaching (a failure or the deadline)
                ax.plot(u[-1], v[-1], marker="X", ms=7, color=colour, mec="k", mew=0.5, zorder=5)
        x0, y0 = _coords(path, a)[0], _coords(path, b)[0]
        ax.plot(x0, y0, "o", color=colour, ms=5)
        # each start named by its number, beside its initial state (the legend says what they are)
        ax.annotate(str(i + 1), (x0, y0), xytext=(-4, 4), textcoords="offset points", ha="right", va="bottom",
                    fontsize=10, fontweight="bold", color=colour)
    T = (0.0, float(sc.steps))
    ax.set_xlim(*_limits(xs, *(T if a is TIME else (sc.low[a], sc.high[a]))))
    ax.set_ylim(*_limits(ys, sc.low[b], sc.high[b]))
    if a is not TIME and math.isclose(sc.high[a] - sc.low[a], sc.high[b] - sc.low[b]):
        ax.set_aspect("equal", adjustable="box")  # same range, presumably the same unit: x–y as a map
    ax.set_xlabel("step" if a is TIME else sc.names[a])
    ax.set_ylabel(sc.names[b])
    ax.grid(alpha=0.3)


def width(ncols: int) -> float:
    """The figure's width in inches for ``ncols`` panels a row (at least :data:`MIN_WIDTH`)."""
    return max(MIN_WIDTH, PANEL[0] * ncols)


def state_space(examples: Sequence[Example]) -> Optional[bytes]:
    """One row per example, one panel per projected pair: the goal (green) and unsafe (red)
    regions' projections, the initial box (dotted), the policy's paths (solid) and the oracle's
    (dashed, the same colour from the same initial state) up to their reach points (stars), or
    to where the policy's episode ended without reaching (a cross)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from .plots import FONT, pyplot

    examples = [e for e in examples if e.policy]
    if not examples:
        return None
    ncols = max(len(e.scene.projection.pairs) for e in examples)
    notes = []
    for ex in examples:
        notes += [f"{ex.title}: {ex.scene.projection.why}"] + [f"{ex.title}: {n}" for n in ex.scene.notes]
    caption = textwrap.wrap("Regions are projections on the plotted coordinates (a ball's disc is both its shadow "
                            "and its slice through the centre; a region not constraining an axis spans it). "
                            + " ".join(n + "." for n in notes), int(CAPTION_CHARS * width(ncols)))
    footer = LEGEND + LINE * (len(caption) + 1)  # inches below the panels: the legend, then the caption
    plt = pyplot()
    plt.rcParams.update(FONT)
    fig, axes = plt.subplots(len(examples), ncols, figsize=(width(ncols), PANEL[1] * len(examples) + footer),
                             squeeze=False)
    for r, ex in enumerate(examples):
        pairs = ex.scene.projection.pairs
        for p in range(ncols):
            ax = axes[r, p]
            if p >= len(pairs):
                ax.axis("off")
                continue
            _panel(ax, ex, p)
            who = (f"{ex.label} (solid), {ex.reference} (dashed)" if ex.oracle is not None
                   else f"{ex.label} only: {ex.missing or 'no oracle'}")
            ax.set_title(f"{ex.title}: {who}", fontsize=10)
    dashed = " or ".join(sorted({e.reference for e in examples if e.oracle is not None})) or "oracle"
    handles = [Line2D([], [], color="k", lw=1.6, label="policy"), Line2D([], [], color="k", ls="--", lw=1.3, label=dashed),
               Line2D([], [], ls="", marker="*", ms=11, color="0.5", mec="k", label="reach point"),
               Line2D([], [], ls="", marker="o", ms=5, color="0.3", label="start 1, 2, ... (one colour each)"),
               Line2D([], [], ls="", marker="X", ms=7, color="0.5", mec="k", label="not reached"),
               Patch(fc="tab:green", alpha=0.3, label="goal"), Patch(fc="tab:red", alpha=0.3, label="unsafe"),
               Patch(fill=False, ec="0.45", ls=":", label="initial box")]
    height = fig.get_figheight()
    fig.legend(handles=handles, fontsize=10, loc="lower center", ncol=4 if ncols < 2 else min(8, 4 * ncols), frameon=False,
               bbox_to_anchor=(0.5, (footer - LEGEND) / height))
    fig.text(0.01, LINE / 2 / height, "\n".join(caption), fontsize=9, va="bottom", ha="left", color="0.25")
    fig.tight_layout(rect=(0, footer / height, 1, 1))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    plt.close(fig)
    return buf.getvalue()


# ---------------------------------------------------------------------------------- asapc eval --plot
def plot_run(run, path: Union[str, Path, None] = None, *, episodes: int = 1000, seed: Optional[int] = None,
             spec: Union[str, Path, None] = None, examples: int = 4) -> Path:
    """Draw a run's policy from the first ``examples`` of its evaluation states (``episodes``
    drawn with ``seed``, default 2024) beside the oracle's cached sequences for those states, and
    write the PNG atomically to ``path`` (default ``RUN/plots/trajectories.png``; a directory: that
    file in it). The oracle is only read from its cache (``asapc eval`` has filled it); without
    it, the policy's paths alone, said in the title. Returns the path written.

    :raises asap_dsl.runs.RunError: the run cannot be read, or the file cannot be written (one sentence).
    """
    from asap_dsl.runfiles import atomic_write, shown
    from asap_dsl.runs import RunDir, RunError
    from asap_dsl.sampling import EVAL_SEED, task_states

    from ..oracle.cache import oracle_for
    from ..rl.evaluation import load_run

    run_dir = run if isinstance(run, RunDir) else RunDir(run)
    target = Path(path).expanduser() if path else run_dir.path / "plots" / "trajectories.png"
    if target.is_dir():
        target = target / "trajectories.png"
    if target.suffix.lower() != ".png":
        raise RunError(f"--plot writes a PNG image: give a path ending in .png (not {shown(target)})")
    seed = EVAL_SEED if seed is None else int(seed)
    owned = run_dir.lock is None
    run_dir.acquire(exclusive=False)  # nobody retrains the run while its model is read
    try:
        loaded = load_run(run_dir, spec)
        prog, cfg = loaded.program, loaded.config
        states = task_states(prog.system, prog.task(cfg.task).model, int(episodes), seed=seed)[:examples]
        cached = oracle_for(prog, cfg.task, seed, int(episodes), compute=False)
        ex, _, _ = example(prog, cfg.task, states, loaded.controller(), cached, cached_only=True,
                           title=f"{Path(prog.file).stem} {cfg.task}", label=f"{cfg.algo} ({cfg.reward} reward)")
    finally:
        if owned:
            run_dir.release()
    atomic_write(target, state_space([ex]))
    return target
