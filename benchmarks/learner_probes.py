"""The learner's probes of :mod:`screen` (benchmarks/screen.py): each replaces a piece of sbx's
SAC (the class, the actor's update, the critic's targets) for one process, so that an idea can be
screened before it is built properly. The environment's probes and the command are screen.py's."""

from __future__ import annotations

import inspect
from functools import partial

import numpy as np

def patch_sbx_class(name: str) -> None:
    import sbx

    from asap_dsl.backends.rl import engines
    from asap_dsl.backends.rl.sb3 import model_kwargs

    cls = getattr(sbx, name)
    accepted = set(inspect.signature(cls.__init__).parameters)

    def build(self, algo, env, settings, seed, tensorboard_log=None):
        engines._configure_jax()
        kw = {k: v for k, v in model_kwargs(algo, env.action_space, settings, self.name).items() if k in accepted}
        return cls("MlpPolicy", env, seed=seed, tensorboard_log=tensorboard_log, verbose=0, **kw)

    engines.SbxEngine.build = build
    engines.SbxEngine.load = lambda self, algo, path, env=None: cls.load(str(path), env=env, device="cpu")


def _sac_actor_loss(actor_state, qf_state, ent_coef_state, params, observations, noise_key, dropout_key,
                    aggregate=None):
    """sbx SAC's own actor loss, ``(loss, log_prob, min_qf_pi)``, for the probes that add to it;
    ``aggregate`` joins the critics' values (their minimum, as sbx, when None)."""
    import jax.numpy as jnp

    dist = actor_state.apply_fn(params, observations)
    actor_actions = dist.sample(seed=noise_key)
    log_prob = dist.log_prob(actor_actions).reshape(-1, 1)
    qf_pi = qf_state.apply_fn(qf_state.params, observations, actor_actions, rngs={"dropout": dropout_key})
    min_qf_pi = (aggregate or jnp.min)(qf_pi, axis=0)
    ent_coef_value = ent_coef_state.apply_fn({"params": ent_coef_state.params})
    return (ent_coef_value * log_prob - min_qf_pi).mean(), log_prob, min_qf_pi


def _critic_step(actor_state, qf_state, ent_coef_state, observations, actions, next_observations, key, target):
    """sbx SAC's critic step with the targets ``target(qf_next, ent_coef, next_log_prob)`` (the target
    critics' values ``[n_critics, batch, 1]`` at the next observations and the actor's sampled
    actions there), returned as sbx's ``update_critic`` returns."""
    import jax

    key, noise_key, dropout_key_target, dropout_key_current = jax.random.split(key, 4)
    dist = actor_state.apply_fn(actor_state.params, next_observations)
    next_actions = dist.sample(seed=noise_key)
    next_log_prob = dist.log_prob(next_actions)
    ent_coef_value = ent_coef_state.apply_fn({"params": ent_coef_state.params})
    qf_next = qf_state.apply_fn(qf_state.target_params, next_observations, next_actions,
                                rngs={"dropout": dropout_key_target})
    y = target(qf_next, ent_coef_value, next_log_prob)

    def mse(params, dropout_key):
        q = qf_state.apply_fn(params, observations, actions, rngs={"dropout": dropout_key})
        return 0.5 * ((y - q) ** 2).mean(axis=1).sum()

    loss, grads = jax.value_and_grad(mse)(qf_state.params, dropout_key_current)
    return qf_state.apply_gradients(grads=grads), (loss, ent_coef_value), key


def _actor_step(actor_state, qf_state, key, actor_loss):
    """One gradient step of the actor on ``actor_loss(params) -> (loss, entropy)``, as sbx returns it."""
    import jax

    (actor_loss_value, entropy), grads = jax.value_and_grad(actor_loss, has_aux=True)(actor_state.params)
    return actor_state.apply_gradients(grads=grads), qf_state, actor_loss_value, key, entropy


def patch_action_search(candidates: int, states: int, beta: float, local: float) -> None:
    """SAC's actor update with a search over actions: on ``states`` of the batch, ``candidates``
    actions (half uniform over [-1, 1]^m, half the mean action plus Gaussian noise of std ``local``)
    are scored by the critics; where the best scores above the policy's own mean action, the mean
    is pulled towards it (squared distance, weighted ``beta`` times the batch's mean |Q|, as
    TD3+BC normalises). The gradient of Q alone climbs the nearest hill of Q over actions; a
    better one elsewhere (reversing before turning) it never reaches."""
    import jax
    import jax.numpy as jnp
    import sbx

    from asap_dsl.backends.rl import engines

    base = sbx.SAC

    @jax.jit
    def update_actor(actor_state, qf_state, ent_coef_state, observations, key):
        key, dropout_key, noise_key, uni_key, loc_key = jax.random.split(key, 5)
        obs_s = observations[:states]
        mean_s = actor_state.apply_fn(actor_state.params, obs_s).mode()
        m = mean_s.shape[-1]
        k_uni = candidates // 2
        uni = jax.random.uniform(uni_key, (k_uni, states, m), minval=-1.0, maxval=1.0)
        loc = jnp.clip(mean_s[None] + local * jax.random.normal(loc_key, (candidates - k_uni, states, m)), -1.0, 1.0)
        cand = jnp.concatenate([uni, loc, mean_s[None]], axis=0)  # [K+1, S, m], the mean last
        kk = cand.shape[0]
        obs_rep = jnp.broadcast_to(obs_s[None], (kk,) + obs_s.shape).reshape(kk * states, -1)
        q = qf_state.apply_fn(qf_state.params, obs_rep, cand.reshape(kk * states, m), rngs={"dropout": dropout_key})
        q = jnp.min(q, axis=0).reshape(kk, states)
        best = jnp.argmax(q[:-1], axis=0)
        target = jnp.take_along_axis(cand[:-1], best[None, :, None], axis=0)[0]
        better = (jnp.max(q[:-1], axis=0) > q[-1]).astype(jnp.float32)
        target = jax.lax.stop_gradient(target)

        def actor_loss(params):
            sac_loss, log_prob, min_qf_pi = _sac_actor_loss(actor_state, qf_state, ent_coef_state, params,
                                                             observations, noise_key, dropout_key)
            mean = actor_state.apply_fn(params, obs_s).mode()
            scale = jax.lax.stop_gradient(jnp.abs(min_qf_pi).mean())
            bc = (better * jnp.sum((mean - target) ** 2, axis=-1)).mean()
            return sac_loss + beta * scale * bc, -log_prob.mean()

        return _actor_step(actor_state, qf_state, key, actor_loss)

    class SearchSAC(base):
        pass

    SearchSAC.update_actor = staticmethod(update_actor)
    orig_model_class = engines.SbxEngine._model_class

    def _model_class(self, algo):
        cls = orig_model_class(self, algo)
        return SearchSAC if algo == "sac" else cls

    engines.SbxEngine._model_class = _model_class


def patch_return_bound(gamma: float, tail: float) -> dict:
    """SAC's critic targets bounded below by the discounted return that followed each stored
    transition: ``max(r + gamma Q', G)``. The dynamics are deterministic, so every realised
    continuation (the learner's own episodes and the oracle's demonstrations) is a feasible one and
    ``G`` a true lower bound on the optimal ``Q`` (an episode cut by its length is completed with
    ``tail``, the least value any continuation has: the failure's floor for ever). What the
    learner once achieved from a hard state is never forgotten by its critic (Monte Carlo
    augmented actor-critic). Returns the counters."""
    import jax
    import jax.numpy as jnp
    import sbx
    from stable_baselines3.common.buffers import ReplayBuffer

    from asap_dsl.backends.rl import demonstrations, engines

    stats = {"episodes": 0, "bounded": 0}

    def ensure(buf):
        if getattr(buf, "mc", None) is None or buf.mc.shape != buf.rewards.shape:
            buf.mc = np.full(buf.rewards.shape, -np.inf, dtype=np.float32)
            buf.mc_rows = [[] for _ in range(buf.n_envs)]
            buf.mc_tracking = True

    orig_add = ReplayBuffer.add

    def add(self, obs, next_obs, action, reward, done, infos):
        ensure(self)
        row = self.pos
        orig_add(self, obs, next_obs, action, reward, done, infos)
        self.mc[row] = -np.inf
        if not self.mc_tracking:
            return
        for k in range(self.n_envs):
            self.mc_rows[k].append(row)
            if done[k]:
                # What follows the last step: the tail's bound after a time-out, nothing after a terminal.
                g = tail if infos[k].get("TimeLimit.truncated", False) else 0.0
                for r_ in reversed(self.mc_rows[k]):
                    g = float(self.rewards[r_, k]) + gamma * g
                    self.mc[r_, k] = g
                stats["episodes"] += 1
                self.mc_rows[k] = []

    ReplayBuffer.add = add
    orig_store = demonstrations.store

    def store(replay_buffer, tr):
        ensure(replay_buffer)
        n, T, pos0 = replay_buffer.n_envs, len(tr), replay_buffer.pos
        g = np.zeros(T, np.float64)
        nxt = 0.0
        for t in range(T - 1, -1, -1):
            if tr.dones[t]:
                nxt = float(tr.rewards[t]) + (gamma * tail if tr.timeouts[t] else 0.0)
            else:
                nxt = float(tr.rewards[t]) + gamma * nxt
            g[t] = nxt
        replay_buffer.mc_tracking = False
        try:
            slots = orig_store(replay_buffer, tr)
        finally:
            replay_buffer.mc_tracking = True
        rows = slots // n
        idx = np.arange(rows * n) % max(T, 1)
        for r in range(rows):
            replay_buffer.mc[(pos0 + r) % replay_buffer.buffer_size] = g[idx[r * n:(r + 1) * n]]
        return slots

    demonstrations.store = store

    @jax.jit
    def update_critic(actor_state, qf_state, ent_coef_state, observations, actions, next_observations, rewards,
                      dones, bound, key):
        def target(qf_next, ent_coef_value, next_log_prob):
            next_q = jnp.min(qf_next, axis=0) - ent_coef_value * next_log_prob[:, None]
            return jnp.maximum(rewards[:, None] + (1 - dones[:, None]) * gamma * next_q, bound[:, None])

        return _critic_step(actor_state, qf_state, ent_coef_state, observations, actions, next_observations, key,
                            target)

    class BoundSAC(sbx.SAC):
        @classmethod
        @partial(jax.jit, static_argnames=["cls", "gradient_steps"])
        def _train_bound(cls, tau, target_entropy, gradient_steps, data, qf_state, actor_state, ent_coef_state, key):
            bs = data[0].shape[0] // gradient_steps

            def one(i, carry):
                qf_state, actor_state, ent_coef_state, key, info = carry
                b = [jax.lax.dynamic_slice_in_dim(x, i * bs, bs) for x in data]
                qf_state, (qf_loss, ent_value), key = update_critic(actor_state, qf_state, ent_coef_state, *b, key)
                qf_state = cls.soft_update(tau, qf_state)
                actor_state, qf_state, ent_coef_state, actor_loss, ent_loss, key = cls.update_actor_and_temperature(
                    actor_state, qf_state, ent_coef_state, b[0], target_entropy, key)
                return qf_state, actor_state, ent_coef_state, key, (actor_loss, qf_loss, ent_loss, ent_value)

            z = jnp.array(0.0)
            return jax.lax.fori_loop(0, gradient_steps, one, (qf_state, actor_state, ent_coef_state, key, (z, z, z, z)))

        def train(self, gradient_steps: int, batch_size: int) -> None:
            buf = self.replay_buffer
            ensure(buf)
            upper = buf.buffer_size if buf.full else buf.pos
            n = batch_size * gradient_steps
            inds = np.random.randint(0, upper, size=n)
            envs = np.random.randint(0, buf.n_envs, size=n)
            bound = buf.mc[inds, envs]
            stats["bounded"] += int(np.isfinite(bound).sum())
            data = (buf.observations[inds, envs], buf.actions[inds, envs], buf.next_observations[inds, envs],
                    buf.rewards[inds, envs].astype(np.float32),
                    (buf.dones[inds, envs] * (1 - buf.timeouts[inds, envs])).astype(np.float32),
                    bound.astype(np.float32))
            self._update_learning_rate(self.policy.actor_state.opt_state,
                                       learning_rate=self.lr_schedule(self._current_progress_remaining),
                                       name="learning_rate_actor")
            self._update_learning_rate(self.policy.qf_state.opt_state,
                                       learning_rate=self.initial_qf_learning_rate or self.lr_schedule(self._current_progress_remaining),
                                       name="learning_rate_critic")
            (self.policy.qf_state, self.policy.actor_state, self.ent_coef_state, self.key,
             (actor_loss, qf_loss, ent_loss, ent_value)) = self._train_bound(
                self.tau, self.target_entropy, gradient_steps, data, self.policy.qf_state, self.policy.actor_state,
                self.ent_coef_state, self.key)
            self._n_updates += gradient_steps
            self.logger.record("train/actor_loss", actor_loss.item())
            self.logger.record("train/critic_loss", qf_loss.item())
            self.logger.record("train/ent_coef", ent_value.item())

    orig_model_class = engines.SbxEngine._model_class
    engines.SbxEngine._model_class = lambda self, algo: BoundSAC if algo == "sac" else orig_model_class(self, algo)
    return stats


def patch_demo_bc(beta: float, q_filter: bool, batch: int = 256) -> dict:
    """SAC's actor also imitates the oracle's demonstrations: on ``batch`` demonstration pairs
    (observation, the oracle's action) drawn each step, the policy's mean is pulled towards the
    oracle's action (squared distance, weighted ``beta`` times the batch's mean |Q|, as TD3+BC
    normalises); with ``q_filter``, only where the critics score the oracle's action above the
    policy's own (Nair et al. 2018). The critic evaluates the policy it has: along an oracle's
    path it learns the oracle's value only once the policy takes the oracle's actions there.
    Returns the counters."""
    import jax
    import jax.numpy as jnp

    from asap_dsl.backends.rl import demonstrations, engines

    pairs: dict = {"obs": [], "act": []}
    stats = {"pairs": 0}
    orig_store = demonstrations.store

    def store(replay_buffer, tr):
        if len(tr):
            pairs["obs"].append(tr.obs)
            pairs["act"].append(np.clip(tr.actions, -0.97, 0.97))  # a tanh mean reaches +-1 only at infinity
            stats["pairs"] = sum(len(a) for a in pairs["act"])
        return orig_store(replay_buffer, tr)

    demonstrations.store = store

    def update_actor(actor_state, qf_state, ent_coef_state, observations, key):
        key, dropout_key, noise_key, pick_key = jax.random.split(key, 4)
        have = bool(pairs["obs"])  # read when traced: the demonstrations are stored before learning
        if have:
            d_obs = jnp.asarray(np.concatenate(pairs["obs"]))
            d_act = jnp.asarray(np.concatenate(pairs["act"]))
            idx = jax.random.randint(pick_key, (batch,), 0, d_obs.shape[0])
            o, a = d_obs[idx], d_act[idx]

        def actor_loss(params):
            loss, log_prob, min_qf_pi = _sac_actor_loss(actor_state, qf_state, ent_coef_state, params,
                                                        observations, noise_key, dropout_key)
            if have:
                mean = actor_state.apply_fn(params, o).mode()
                w = jnp.ones(batch)
                if q_filter:
                    q_demo = jnp.min(qf_state.apply_fn(qf_state.params, o, a, rngs={"dropout": dropout_key}), axis=0)
                    q_own = jnp.min(qf_state.apply_fn(qf_state.params, o, jax.lax.stop_gradient(mean),
                                                      rngs={"dropout": dropout_key}), axis=0)
                    w = jax.lax.stop_gradient((q_demo[:, 0] > q_own[:, 0]).astype(jnp.float32))
                scale = jax.lax.stop_gradient(jnp.abs(min_qf_pi).mean())
                loss = loss + beta * scale * (w * jnp.sum((mean - a) ** 2, axis=-1)).mean()
            return loss, -log_prob.mean()

        return _actor_step(actor_state, qf_state, key, actor_loss)

    orig_model_class = engines.SbxEngine._model_class
    made: dict = {}

    def _model_class(self, algo):
        cls = orig_model_class(self, algo)
        if algo != "sac":
            return cls
        if cls not in made:  # on top of any other probe's SAC (the return bound's critic)
            made[cls] = type("ImitatingSAC", (cls,), {"update_actor": staticmethod(jax.jit(update_actor))})
        return made[cls]

    engines.SbxEngine._model_class = _model_class
    return stats


def patch_actor_ema(tau: float) -> dict:
    """Validation (and so the kept model) judges an exponential moving average of the actor's
    parameters instead of the latest ones: after every call of SAC's ``train`` (four gradient steps
    in the default) the average moves ``tau`` of the way to the current parameters. SAC's actor
    keeps moving on a plateau; its average is a smoother law (Polyak averaging of the iterates).
    The learner itself still acts and learns with its latest parameters. Returns the counters."""
    import jax

    from asap_dsl.backends.rl import engines
    from asap_dsl.backends.rl import session as session_module

    stats = {"updates": 0, "tau": tau}
    step = jax.jit(lambda e, x: jax.tree_util.tree_map(lambda a, b: (1.0 - tau) * a + tau * b, e, x))
    orig_model_class = engines.SbxEngine._model_class
    made: dict = {}

    def averaged(cls):
        def train(self, gradient_steps: int, batch_size: int) -> None:
            cls.train(self, gradient_steps, batch_size)
            params = self.policy.actor_state.params
            ema = getattr(self, "_ema_params", None)
            self._ema_params = params if ema is None else step(ema, params)
            stats["updates"] += 1

        return type("AveragedSAC", (cls,), {"train": train})

    def _model_class(self, algo):
        cls = orig_model_class(self, algo)
        if algo != "sac":
            return cls
        if cls not in made:
            made[cls] = averaged(cls)
        return made[cls]

    engines.SbxEngine._model_class = _model_class
    orig_validate = session_module.Session.validate

    def validate(self, model, steps, logger=None):
        ema = getattr(model, "_ema_params", None)
        if ema is None:
            return orig_validate(self, model, steps, logger)
        live = model.policy.actor_state
        model.policy.actor_state = live.replace(params=ema)
        try:
            return orig_validate(self, model, steps, logger)
        finally:  # the live parameters back, whatever else the validation's rules changed
            model.policy.actor_state = model.policy.actor_state.replace(params=live.params)

    session_module.Session.validate = validate
    return stats


def patch_critic_mean(target: bool) -> dict:
    """SAC's actor climbs the mean of its critics instead of their minimum (and, with ``target``, the
    critics' targets take the mean too: no clipped double-Q). The minimum is a pessimism against
    the over-estimates of noisy targets; at the goal's boundary, where the fastest path grazes the
    goal (the oracle enters at ρ ~1e-4, the policies 0.002-0.015 deep and a step later), it also
    prices a grazing entry by the critic that doubts it most. The dynamics are deterministic. (Not
    with the imitation: its actor update is its own, :mod:`asap_dsl.backends.rl.imitation`.)"""
    import jax
    import jax.numpy as jnp
    import sbx

    from asap_dsl.backends.rl import engines

    @jax.jit
    def update_actor(actor_state, qf_state, ent_coef_state, observations, key):
        key, dropout_key, noise_key = jax.random.split(key, 3)

        def actor_loss(params):
            loss, log_prob, _ = _sac_actor_loss(actor_state, qf_state, ent_coef_state, params, observations,
                                                noise_key, dropout_key, aggregate=jnp.mean)
            return loss, -log_prob.mean()

        return _actor_step(actor_state, qf_state, key, actor_loss)

    @jax.jit
    def update_critic(actor_state, qf_state, ent_coef_state, observations, actions, next_observations, rewards,
                      dones, discounts, key):
        def target(qf_next, ent_coef_value, next_log_prob):
            next_q = jnp.mean(qf_next, axis=0) - ent_coef_value * next_log_prob[:, None]
            return rewards[:, None] + (1 - dones[:, None]) * discounts[:, None] * next_q

        return _critic_step(actor_state, qf_state, ent_coef_state, observations, actions, next_observations, key,
                            target)

    orig_model_class = engines.SbxEngine._model_class
    made: dict = {}

    def _model_class(self, algo):
        cls = orig_model_class(self, algo)
        if algo != "sac" or not issubclass(cls, sbx.SAC):
            return cls
        if cls not in made:
            members = {"update_actor": staticmethod(update_actor)}
            if target:
                members["update_critic"] = staticmethod(update_critic)
            made[cls] = type("MeanCriticSAC", (cls,), members)
        return made[cls]

    engines.SbxEngine._model_class = _model_class
    return {"critic_mean": "actor and target" if target else "actor"}
