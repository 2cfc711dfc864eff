"""The oracle's action sequences as demonstrations in an off-policy learner's replay buffer.

On a system with known dynamics (``ode`` or ``map``) the minimum-time oracle
(:mod:`asap_dsl.backends.oracle`) finds, from an initial state, an action sequence that reaches
``asap`` while ``avoid`` stays false and the state inside the state space; on a black box
(``simulator``) the sampling planner does (:mod:`asap_dsl.backends.oracle.planning`: not the
fastest sequence, one that reaches, which is what a learner that never reaches needs). Replayed through the
very environment the learner trains in — the same simulator, reward, observation and action
scaling, episode ends and SB3's time-limit handling — each step of such a sequence is a true
transition of the learner's own MDP: an exact witness, not an approximation of one. Before
learning starts, :func:`add_demonstrations` stores those transitions in ``model.replay_buffer``
(SAC, TD3 and DDPG, on either engine: sbx uses stable-baselines3's ``ReplayBuffer``).

The initial states come from the task's init box with a seed derived from the run's own
(:func:`demonstration_seed`), never the evaluation seed nor the validation seed: a policy is
not shown the answers to the states it is judged on. A sequence whose replay does not reach the
goal (the env's ``t_reach``) or fails on the way is dropped.
"""

from __future__ import annotations

import functools
import time
from dataclasses import asdict, dataclass, replace
from typing import Any, Callable, Optional, Sequence

import numpy as np

from asap_dsl.sampling import EVAL_SEED, task_states

from .config import VALIDATION_SEED
from .presets import OFF_POLICY

__all__ = ["DEMONSTRATION_PLANNER_STEPS_PER_SECOND", "DEMONSTRATION_SEED_OFFSET", "DEMONSTRATION_STATE_SECONDS",
           "Demonstrations", "Witnesses", "add_demonstrations", "demonstration_seed", "keep", "longest", "replay",
           "search", "search_budget_text", "search_count", "searcher", "solve", "store", "unavailable"]

#: Added to the run's seed for the demonstrations' initial states (and their episode lengths).
#: Larger than both fixed seeds, so that no run's seed can map onto them.
DEMONSTRATION_SEED_OFFSET = 10_007
#: The search time per demonstration state: a hard state is given up, not waited for. On known
#: dynamics it (and the search's budget) is read on the oracle's simulated clock, its solves' work
#: priced in CPU seconds (:class:`~asap_dsl.backends.oracle.clock.WorkClock`), for the reason below.
DEMONSTRATION_STATE_SECONDS = 5.0
#: On a black box those seconds are the planner's simulated clock, this many simulator steps a
#: second, not the wall clock: a run's demonstrations, and so the run, are the same on every
#: machine (on the wall clock a machine three times slower found 9 of the swimmer's 36 where the
#: reports' found 30, and its run stalled at 18% within 50 steps instead of 100%). About the
#: planner's speed on the 2-core machine of docs/results; a slower one searches longer.
DEMONSTRATION_PLANNER_STEPS_PER_SECOND = 60_000.0


def search_budget_text(prog, budget_seconds: Optional[float], state_seconds: float = DEMONSTRATION_STATE_SECONDS,
                       wall_capped: bool = False) -> str:
    """How long the search may take, for the run's log line: the time per state (and the
    oracle's budget in all) on the searcher's simulated clock (its wall time follows the machine;
    under ``wall_capped``, a run's time limit, the budget caps it as well)."""
    cap = "" if budget_seconds is None or not wall_capped else f", for at most {budget_seconds:.0f} s"
    if searcher(prog) == "planner":
        return (f", {state_seconds:g} s each on the planner's clock "
                f"({DEMONSTRATION_PLANNER_STEPS_PER_SECOND:,.0f} simulator steps a second)" + cap)
    in_all = "" if budget_seconds is None else f" and {budget_seconds:.0f} s in all"
    return f", {state_seconds:g} s each{in_all} on the oracle's clock (its solves' work in CPU seconds)" + cap


def demonstration_seed(run_seed: int) -> int:
    """The seed of a run's demonstration states: never :data:`EVAL_SEED` nor the validation seed."""
    seed = int(run_seed) + DEMONSTRATION_SEED_OFFSET
    assert seed not in (EVAL_SEED, VALIDATION_SEED)
    return seed


def unavailable(prog, algo: str) -> Optional[str]:
    """Why a run of ``algo`` on ``prog`` cannot have demonstrations (None when it can)."""
    if algo not in OFF_POLICY:
        return f"{algo} has no replay buffer (only {', '.join(OFF_POLICY)} do)"
    return None  # known dynamics: the oracle; a black box: the planner (:func:`solve`)


@dataclass(frozen=True)
class Demonstrations:
    """What :func:`add_demonstrations` did: ``states`` drawn, ``solved`` by the oracle within an
    episode, ``replays`` of them chosen (:func:`longest`: the longest, repeated), ``added`` replays
    stored (they reached the goal), ``transitions`` stored,
    the oracle's and the whole step's wall time; ``reason`` why none were tried."""

    states: int = 0
    solved: int = 0
    replays: int = 0
    added: int = 0
    transitions: int = 0
    rows: int = 0  # the replay buffer's rows they fill (at the start: kept for the whole run, :func:`keep`)
    start_row: int = 0  # ... from this one (0 at the start of a run; the late rule's come later)
    oracle_seconds: float = 0.0
    seconds: float = 0.0
    seed: Optional[int] = None
    reason: Optional[str] = None
    cached: bool = False  # the oracle's sequences were read back from the cache (its seconds charged all the same)
    searcher: str = "oracle"  # or the planner, on a black box (:func:`searcher`)

    def to_dict(self) -> dict:
        return asdict(self)

    def text(self) -> str:
        """One line for the training log."""
        if self.reason is not None:
            return f"demonstrations: none ({self.reason})"
        chosen = "" if self.replays == self.solved else f", {self.replays} replays of the longest"
        where = ", read back from the cache" if self.cached else ""
        return (f"demonstrations: {self.solved} of {self.states} states solved by the {self.searcher} in "
                f"{self.oracle_seconds:.1f} s (seed {self.seed}{where}){chosen}, {self.added} stored: {self.transitions:,} "
                f"transitions in the replay buffer ({self.seconds:.1f} s in all)")


@dataclass
class Transitions:
    """Transitions as the learner's replay buffer takes them, one row each: observations and next
    observations as the policy sees them, the buffer's actions (in [-1, 1]), the env's rewards,
    ``dones`` and ``timeouts`` (SB3's ``TimeLimit.truncated``)."""

    obs: np.ndarray
    next_obs: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray
    timeouts: np.ndarray

    def __len__(self) -> int:
        return len(self.rewards)


@functools.lru_cache(maxsize=1)
def _start_at_class():
    """Built on first use: stable-baselines3 (and torch) load only when a replay runs."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class StartAt(VecEnvWrapper):
        """A vector env whose ``reset`` starts every entry at given states and episode lengths
        (the rest passes through): the bottom of the learner's wrapper stack for a replay."""

        def __init__(self, venv, states: np.ndarray, k: np.ndarray):
            super().__init__(venv)
            self.states, self.k = states, k

        def reset(self):
            return self.venv.core.start(self.states, self.k)

        def step_wait(self):
            return self.venv.step_wait()

    return StartAt


def replay(prog, task: str, reward: Any, wrap: Callable, policy_action: Callable[[np.ndarray], np.ndarray],
           buffer_action: Callable[[np.ndarray], np.ndarray], starts: np.ndarray, sequences: list[np.ndarray],
           lengths: np.ndarray, failure_reward: Optional[float] = None) -> tuple[Transitions, np.ndarray]:
    """Replay each action sequence (environment units, ``[N_i, m]``) from its initial state
    through the learner's environment and collect the transitions as SB3's off-policy collection
    stores them (``_store_transition``: a finished entry's next observation is its
    ``terminal_observation``, its timeout ``TimeLimit.truncated``).

    :param wrap: the learner's wrappers around a raw vector env (scaling, time-limit handling).
    :param policy_action: environment actions ``[B, m]`` to the actions the policy would give.
    :param buffer_action: the policy's actions to what the replay buffer stores.
    :param lengths: the episode length of each replay (at least its sequence's length).
    :param failure_reward: the learner's reward of a failure step (the run's ``failure_reward``).
    :return: the transitions of the sequences that reached the goal without failing, and which
        those were (a bool per sequence).
    """
    from asap_dsl.env import make_vec_env

    B = len(sequences)
    raw = make_vec_env(prog, task, num_envs=B, reward=reward, failure_reward=failure_reward)
    env = wrap(_start_at_class()(raw, np.asarray(starts, float), np.asarray(lengths, np.int64)))
    obs = env.reset()
    m = raw.action_space.shape[0]
    n_steps = np.array([len(s) for s in sequences])
    alive = np.ones(B, dtype=bool)   # still replaying its sequence
    reached = np.zeros(B, dtype=bool)
    rows: list[list[tuple]] = [[] for _ in range(B)]
    centre = policy_action(((raw.action_space.low + raw.action_space.high) / 2.0)[None].astype(np.float64))[0]
    for t in range(int(n_steps.max(initial=0))):
        acts = np.tile(centre, (B, 1))  # entries past their sequence act too (the batch steps together)
        for i in np.flatnonzero(alive):
            acts[i] = policy_action(np.asarray(sequences[i][t], float).reshape(1, m))[0]
        env.step_async(acts)
        new_obs, rew, done, infos = env.step_wait()
        for i in np.flatnonzero(alive):
            info = infos[i]
            nxt = info["terminal_observation"] if done[i] else new_obs[i]
            rows[i].append((obs[i].copy(), np.array(nxt, np.float32), buffer_action(acts[i:i + 1])[0], float(rew[i]),
                            bool(done[i]), bool(info.get("TimeLimit.truncated", False))))
            failed = done[i] and info.get("end_reason") != "time_limit"
            if failed:
                alive[i] = False
            elif done[i] or t + 1 == n_steps[i]:
                alive[i] = False
                reached[i] = info.get("t_reach") is not None
        obs = new_obs
    kept = [r for i in range(B) if reached[i] for r in rows[i]]
    n_obs, n_act = env.observation_space.shape[0], m
    if not kept:
        z = np.zeros((0, n_obs), np.float32)
        return Transitions(z, z.copy(), np.zeros((0, n_act), np.float32), np.zeros(0, np.float32),
                           np.zeros(0, bool), np.zeros(0, bool)), reached
    cols = list(zip(*kept))
    return Transitions(np.stack(cols[0]).astype(np.float32), np.stack(cols[1]).astype(np.float32),
                       np.stack(cols[2]).astype(np.float32), np.asarray(cols[3], np.float32),
                       np.asarray(cols[4], bool), np.asarray(cols[5], bool)), reached


def store(replay_buffer, tr: Transitions) -> int:
    """Add the transitions to an SB3 ``ReplayBuffer`` through its own ``add`` (one row of
    ``n_envs`` transitions per call); returns the slots filled. A last, partial row is completed
    with the first transitions again: every transition is stored at least once, and no slot the
    learner samples holds anything but a replayed transition."""
    n, T = replay_buffer.n_envs, len(tr)
    if T == 0:
        return 0
    rows = min(-(-T // n), replay_buffer.buffer_size)
    idx = np.arange(rows * n) % T
    for r in range(rows):
        j = idx[r * n:(r + 1) * n]
        infos = [{"TimeLimit.truncated": bool(x)} for x in tr.timeouts[j]]
        replay_buffer.add(tr.obs[j], tr.next_obs[j], tr.actions[j], tr.rewards[j], tr.dones[j], infos)
    return rows * n


def keep(replay_buffer, ranges: Sequence[tuple[int, int]]) -> None:
    """Keep the ring buffer's ``(start, rows)`` ranges (the demonstrations: at its start, or where
    the late rule stored them mid-run) for the whole run: once it has wrapped round, its next row
    is the first after them, not theirs. Called before each store. A replay buffer fills in a few
    minutes at a few thousand steps per second; without this, the oracle's witnesses would be the
    first transitions it forgets, and an actor imitating those rows would imitate whatever
    overwrote them (the pendulum's and the puck's validation fell by 30–60 points at the step the
    ring reached the late rule's rows). A range that would fill half of it or more is not kept
    (the learner's own transitions need the room)."""
    if not replay_buffer.full:
        return
    kept = [(s, r) for s, r in ranges if 0 < r < replay_buffer.buffer_size // 2]
    for _ in kept:  # leaving one range may land in the next (one that ends at the buffer's end: at row 0)
        inside = next(((s, r) for s, r in kept if s <= replay_buffer.pos < s + r), None)
        if inside is None:
            return
        replay_buffer.pos = (inside[0] + inside[1]) % replay_buffer.buffer_size


def make_room(replay_buffer, transitions: int) -> None:
    """Grow a replay buffer that has not yet wrapped round by the rows ``transitions`` fill, so
    that storing them mid-run overwrites nothing later (the late rule's paths for the actor to
    imitate, :mod:`.exploration`): the buffer was sized for the run's own steps, and a run where
    the rule never fires pays no memory for them. A buffer that has wrapped stays as it is."""
    n = replay_buffer.n_envs
    extra = -(-int(transitions) // n)
    if extra <= 0 or replay_buffer.full:
        return
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
        a = getattr(replay_buffer, name, None)
        if isinstance(a, np.ndarray) and a.ndim >= 2 and a.shape[0] == replay_buffer.buffer_size:
            setattr(replay_buffer, name, np.concatenate([a, np.zeros((extra, *a.shape[1:]), a.dtype)]))
    replay_buffer.buffer_size += extra


@dataclass
class Witnesses:
    """The oracle's action sequences for a run's demonstration states: ``starts [K, n]``, one
    sequence ``[N_i, m]`` each (environment units, ``1 <= N_i <=`` the longest episode) and the
    episode length of its replay; ``states`` searched, drawn with ``seed``, of which ``solved``
    gave a sequence (before :func:`longest` chose among them); ``reason`` why none were sought."""

    seed: int
    states: int
    starts: np.ndarray
    sequences: list
    lengths: np.ndarray
    oracle_seconds: float = 0.0
    reason: Optional[str] = None
    solved: Optional[int] = None
    cached: bool = False  # read back from the cache (``oracle_seconds`` are then the search's that stored it)

    def __post_init__(self) -> None:
        if self.solved is None:
            self.solved = len(self.sequences)

    def to_json(self) -> dict:
        return {"seed": self.seed, "states": self.states, "solved": self.solved, "oracle_seconds": self.oracle_seconds,
                "starts": np.asarray(self.starts, float).tolist(), "lengths": np.asarray(self.lengths).tolist(),
                "sequences": [np.asarray(q, float).tolist() for q in self.sequences]}

    @classmethod
    def from_json(cls, data: dict, n: int) -> "Witnesses":
        starts = np.asarray(data["starts"], float).reshape(-1, n)
        seqs = [np.asarray(q, float) for q in data["sequences"]]
        lengths = np.asarray(data["lengths"], np.int64)
        if not (len(starts) == len(seqs) == len(lengths)):
            raise ValueError("inconsistent witnesses")
        return cls(int(data["seed"]), int(data["states"]), starts, seqs, lengths, float(data["oracle_seconds"]),
                   solved=int(data["solved"]), cached=True)


def searcher(prog) -> str:
    """Who finds the sequences: the ``oracle`` on known dynamics, the ``planner`` on a black box."""
    return "planner" if prog.system.kind == "simulator" else "oracle"


def search_count(prog, count: int, state_seconds: float = DEMONSTRATION_STATE_SECONDS,
                 budget_seconds: Optional[float] = None) -> int:
    """The states :func:`solve` draws for ``count`` asked. The oracle takes them in batches until
    the budget is spent; the planner's pilot runs once per call, so it takes all in one call: as
    many as the budget plans at the time per state, on however many cores the machine has (the
    budget is read as CPU seconds: on one core the search takes longer, it does not find fewer).
    A count that followed the cores made a sweep's one-core workers draw half the states of a
    two-core run, and the swimmer's reach_avoid seed 1 then learnt from 6 solved states (19%
    within 50 steps, docs/training.md "Where the rule fails")."""
    if searcher(prog) == "planner" and budget_seconds is not None:
        return min(int(count), max(1, int(budget_seconds / state_seconds)))
    return int(count)


def solve(prog, task: str, count: int, run_seed: int, *, workers: Optional[int] = None,
          state_seconds: float = DEMONSTRATION_STATE_SECONDS, budget_seconds: Optional[float] = None,
          check_stop: Optional[Callable[[], None]] = None, cache: bool = True,
          restarts: Optional[int] = None, wall_capped: bool = False) -> Witnesses:
    """Draw ``count`` initial states of ``task`` (seed :func:`demonstration_seed` of ``run_seed``)
    and solve them with the oracle or the planner (``workers`` processes; default one per core).
    With ``budget_seconds`` the search stops taking states once the budget is spent (the states
    not reached are left out). A sequence longer than the task's longest episode is left
    out, as is a state already in the goal; each replay's episode length is drawn from the task's
    range, at least its sequence's length. ``check_stop()`` is called as the oracle progresses (it
    raises to abandon the search). ``restarts``: the oracle's extra initial guesses per horizon
    (default: its own, :data:`~asap_dsl.backends.oracle.search.RESTARTS` on non-linear dynamics).
    Both searchers read the times on their simulated clocks, so that the search is the same on
    every machine: the planner's budget sets how many states it takes, the oracle's is shared out
    over its chunks of states (:func:`~asap_dsl.backends.oracle.solver.run`). ``wall_capped``: the
    budget also caps the search's wall time (a run with a time limit, which is the wall clock's).

    With ``cache``, what was found is kept beside the oracle's cache (per spec hash, task, seed,
    count, time per state and budget) and read back by the next run that asks the same: a sweep's
    runs of one seed (every reward and algorithm) learn from the same sequences, and each is
    charged the search's seconds all the same, so that time-limited runs stay comparable.
    """
    from asap_dsl.limits import available_cores

    from ..oracle.clock import WorkClock
    from ..oracle.goals import OracleUnsupported
    from ..oracle.planner import PlannerBudget, PlannerUnsupported
    from ..oracle.planning import plan_states
    from ..oracle.solver import run as run_oracle

    start = time.perf_counter()
    seed = demonstration_seed(run_seed)
    tm = prog.task(task).model
    n = prog.system.n_state
    black_box = searcher(prog) == "planner"
    asked = int(count)
    count = search_count(prog, count, state_seconds, budget_seconds)
    # The planner's entries are named by the states it searched (their number is the rule's, not the ask's).
    wall = wall_capped and budget_seconds is not None
    clock = WorkClock()
    tag = f"k{DEMONSTRATION_PLANNER_STEPS_PER_SECOND:g}" if black_box else f"c{clock.tag()}"
    path = (_cache_path(prog, task, seed, count if black_box else asked, state_seconds, budget_seconds, restarts,
                        tag, wall) if cache else None)
    if path is not None:
        hit = _load(path, n)
        if hit is not None:
            return hit
    states = task_states(prog.system, tm, int(count), seed=seed)
    if workers is None:  # (the workers are spawned from a process that runs a learner)
        workers = available_cores()
    n_workers = max(1, min(int(workers), len(states)))
    progress = None if check_stop is None else (lambda _k: check_stop())
    try:
        if black_box:
            report = plan_states(prog, task, states=states, workers=n_workers, time_limit=state_seconds,
                                 progress=progress, budget_seconds=budget_seconds if wall else None,
                                 budget=PlannerBudget(steps_per_second=DEMONSTRATION_PLANNER_STEPS_PER_SECOND))
        else:  # under a budget each chunk of the oracle's states stops once its share is spent
            report = run_oracle(prog, task, states=states, workers=n_workers, time_limit=state_seconds,
                                progress=progress, budget_seconds=budget_seconds, restarts=restarts,
                                clock=clock, wall_seconds=budget_seconds if wall else None)
        results = list(report.results)
    except (OracleUnsupported, PlannerUnsupported) as err:
        return Witnesses(seed, len(states), np.zeros((0, n)), [], np.zeros(0, np.int64),
                         time.perf_counter() - start, f"the {searcher(prog)} does not treat this task: {err}")
    kmin, kmax = tm.episode
    usable = [r for r in results if r.status == "solved" and r.actions is not None and r.steps is not None
              and 1 <= max(len(r.actions), r.steps) <= kmax]
    # A planned sequence may end before its reach: it coasts there on zero actions (the planner's
    # replay, SequenceController), which the witness then spells out.
    sequences = [np.concatenate([np.asarray(r.actions, float).reshape(len(r.actions), -1),
                                 np.zeros((max(0, r.steps - len(r.actions)), prog.system.n_action))])
                 for r in usable]
    rng = np.random.default_rng([seed, 1])
    lengths = np.array([rng.integers(max(kmin, len(q)), kmax + 1) for q in sequences], dtype=np.int64)
    starts = np.stack([np.asarray(r.x0, float) for r in usable]) if usable else np.zeros((0, n))
    found = Witnesses(seed, len(results), starts, sequences, lengths, time.perf_counter() - start)
    if path is not None:
        from asap_dsl.runs import atomic_write_json

        try:
            atomic_write_json(path, found.to_json())
        except OSError:  # a cache that cannot be written: the next run searches again
            pass
    return found


def search(prog, task: str, count: int, run_seed: int, tell: Callable[[str], None], head: str, *,
           state_seconds: float, budget_seconds: Optional[float], time_limit: Optional[float],
           check_stop: Optional[Callable[[], None]] = None, restarts: Optional[int] = None) -> Witnesses:
    """:func:`solve` as a training run calls it: first one line to its progress, ``head`` (what set
    the search off) then the searcher, its states and its budget; every core works on it (the
    searchers spawn their workers from a process that may run a learner: forking JAX's or torch's
    threads is not safe), and their clocks make what they find the same on one core as on two.
    A run's ``time_limit`` is the wall clock's: there the budget caps the search's wall time too."""
    wall_capped = time_limit is not None
    n = search_count(prog, count, state_seconds, budget_seconds)
    tell(f"{head}: the {searcher(prog)} on {n:,} initial states of the run's own seed for demonstrations"
         + search_budget_text(prog, budget_seconds, state_seconds, wall_capped) + " ...")
    return solve(prog, task, count, run_seed, state_seconds=state_seconds, budget_seconds=budget_seconds,
                 check_stop=check_stop, wall_capped=wall_capped, restarts=restarts)


def _cache_path(prog, task: str, seed: int, count: int, state_seconds: float, budget: Optional[float],
                restarts: Optional[int] = None, clock: str = "", wall: bool = False):
    """The cache file of these witnesses; ``clock`` names the searcher's simulated clock."""
    from asap_dsl.runs import spec_hash

    from ..oracle.cache import cache_dir

    bound = "none" if budget is None else f"{float(budget):g}"
    return (cache_dir() / "demonstrations"
            / (f"{spec_hash(prog.source)[:16]}-{task}-s{seed}-n{count}-t{float(state_seconds):g}-b{bound}"
               + ("" if restarts is None else f"-r{int(restarts)}")
               + ("" if not clock else f"-{clock}")
               + ("-wall" if wall else "") + ".json"))


def _load(path, n: int) -> Optional[Witnesses]:
    """Cached witnesses, or None where absent or damaged (then searched again)."""
    import json

    try:
        return Witnesses.from_json(json.loads(path.read_text(encoding="utf-8")), n)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def longest(witnesses: Witnesses, share: float = 1.0, repeat: int = 1) -> Witnesses:
    """The longest ``share`` of the witnesses' sequences (at least one, ties at the cut kept),
    each ``repeat`` times: the manoeuvres a learner seldom finds by itself (backing up, looping,
    swinging), weighted in the replay buffer. ``share`` 1 and ``repeat`` 1 keep them as they are."""
    if not 0.0 < share <= 1.0 or int(repeat) < 1:
        raise ValueError(f"share must be in (0, 1] and repeat at least 1; got {share}, {repeat}")
    w = witnesses
    if not w.sequences or (share >= 1.0 and repeat == 1):
        return w
    steps = np.array([len(s) for s in w.sequences])
    keep_n = max(1, int(np.ceil(share * len(steps))))
    cut = np.sort(steps)[::-1][keep_n - 1]
    keep = [i for i in range(len(steps)) if steps[i] >= cut for _ in range(int(repeat))]
    return replace(w, starts=w.starts[keep], sequences=[w.sequences[i] for i in keep], lengths=w.lengths[keep])


def add_demonstrations(prog, task: str, model, wrap: Callable, scaling, witnesses: Witnesses,
                       reward: Any = None, failure_reward: Optional[float] = None,
                       grow: bool = False) -> Demonstrations:
    """Replay each of the oracle's sequences through the learner's environment (``wrap`` and
    ``scaling``: :class:`~asap_dsl.backends.rl.sb3.Scaling`) and store the transitions of those
    that reach the goal in ``model.replay_buffer`` (with ``grow``, in rows it adds for them:
    :func:`make_room`); returns what was done."""
    start = time.perf_counter()
    w = witnesses
    if w.reason is not None:
        return Demonstrations(states=w.states, seed=w.seed, oracle_seconds=w.oracle_seconds,
                              seconds=w.oracle_seconds, reason=w.reason, searcher=searcher(prog))
    added = stored = rows = first_row = 0
    if w.sequences:
        def buffer_action(u: np.ndarray) -> np.ndarray:  # as SB3's _sample_action stores it
            return np.clip(model.policy.scale_action(u), -1.0, 1.0)

        tr, reached = replay(prog, task, reward, wrap, scaling.policy_action, buffer_action, w.starts, w.sequences,
                             w.lengths, failure_reward)
        added, stored = int(reached.sum()), len(tr)
        if grow:
            make_room(model.replay_buffer, stored)
        first_row = int(model.replay_buffer.pos)
        rows = store(model.replay_buffer, tr) // model.replay_buffer.n_envs
    return Demonstrations(states=w.states, solved=int(w.solved), replays=len(w.sequences), added=added,
                          transitions=stored, rows=rows, start_row=first_row, cached=w.cached,
                          oracle_seconds=w.oracle_seconds, seconds=w.oracle_seconds + time.perf_counter() - start,
                          seed=w.seed, searcher=searcher(prog))
