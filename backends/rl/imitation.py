"""SAC whose actor also imitates the oracle's minimum-time paths kept in its replay buffer.

The oracle's sequences are exact witnesses of the goal (:mod:`.demonstrations`), and on known
dynamics they are minimum-time: every (state, action) pair along one is optimal from that state.
In the replay buffer alone they teach the critic what reaching the goal pays; the actor still
climbs its own critic's nearest hill. On the attitude benchmark, SAC stayed 3-5 points under the
ceiling at every tolerance however long it trained, while a network of the same kind fitted to
4,000 of the oracle's paths came within 1.0 / 1.3 / 1.0 points (``benchmarks/imitation.py``,
docs/training.md "Imitating the oracle at scale"): the gap was the learner's, not the policy's.

Here the actor's loss is SAC's plus an imitation term on a batch of the demonstrations drawn at
each gradient step (the rows the run keeps at the start of its replay buffer, or those the late
rule stored when the run found nothing, :mod:`.exploration`): the squared
distance of the policy's mean action from the oracle's, weighted ``imitation_weight`` times the
batch's mean |Q| (as TD3+BC normalises, so that the weight does not depend on the reward's
scale). SAC still learns from the reward; where the oracle's paths do not go, the critic leads.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

__all__ = ["ACTION_MARGIN", "IMITATION_STATE_SECONDS", "imitating_sac", "set_imitation"]

#: The oracle's time per state for the paths the actor imitates: the hard states, the long
#: manoeuvres the learner misses, are the ones a short cap drops (attitude: 6% timed out at 5 s,
#: 2% were not solved at 30 s, for 16% more time).
IMITATION_STATE_SECONDS = 15.0
# `--imitation`'s search tries no second initial guess at a horizon the first found infeasible: on
# 80 attitude states 0.73 s a state against 1.05, one minimum a step longer (the session passes
# restarts=0). The late rule's search keeps it (:mod:`.exploration`: the pendulum's paths need it).

#: The oracle's actions are pulled inside the action box by this share: the policy's tanh reaches
#: the bounds only at infinity, and a bang-bang optimum sits on them.
ACTION_MARGIN = 0.03

_ImitatingSAC = None


def set_imitation(model, weight: float, rows: int, start: int = 0) -> None:
    """The model's actor imitates ``rows`` rows of its replay buffer from row ``start`` (the
    oracle's transitions: kept at its start, or stored mid-run by the late rule) with ``weight``;
    0 for either turns imitation off."""
    model.imitation_weight = float(weight)
    model.imitation_rows = int(rows)
    model.imitation_start = int(start)


def imitating_sac():
    """sbx's SAC with the imitation term (defined on first use: it imports JAX). With a weight of 0
    or no demonstration rows it trains exactly as sbx's SAC."""
    global _ImitatingSAC
    if _ImitatingSAC is not None:
        return _ImitatingSAC
    import jax
    import jax.numpy as jnp
    import sbx
    from sbx.common.type_aliases import ReplayBufferSamplesNp

    def update_actor(actor_state, qf_state, ent_coef_state, observations, demo_obs, demo_actions, weight, key):
        key, dropout_key, noise_key = jax.random.split(key, 3)

        def actor_loss(params):
            dist = actor_state.apply_fn(params, observations)
            actions = dist.sample(seed=noise_key)
            log_prob = dist.log_prob(actions).reshape(-1, 1)
            min_qf_pi = jnp.min(qf_state.apply_fn(qf_state.params, observations, actions,
                                                  rngs={"dropout": dropout_key}), axis=0)
            ent_coef = ent_coef_state.apply_fn({"params": ent_coef_state.params})
            loss = (ent_coef * log_prob - min_qf_pi).mean()
            mean = actor_state.apply_fn(params, demo_obs).mode()
            scale = jax.lax.stop_gradient(jnp.abs(min_qf_pi).mean())
            loss = loss + weight * scale * jnp.sum((mean - demo_actions) ** 2, axis=-1).mean()
            return loss, -log_prob.mean()

        (loss_value, entropy), grads = jax.value_and_grad(actor_loss, has_aux=True)(actor_state.params)
        return actor_state.apply_gradients(grads=grads), loss_value, key, entropy

    class ImitatingSAC(sbx.SAC):
        imitation_weight: float = 0.0
        imitation_rows: int = 0
        imitation_start: int = 0

        def train(self, gradient_steps: int, batch_size: int) -> None:
            if self.imitation_weight <= 0 or self.imitation_rows <= 0 or self.policy_delay != 1:
                return super().train(gradient_steps, batch_size)
            buf = self.replay_buffer
            n = batch_size * gradient_steps
            data = buf.sample(n, env=self._vec_normalize_env)
            # The demonstrations' batch: the rows they fill, any environment column.
            lo = min(self.imitation_start, buf.buffer_size - 1)
            rows = np.random.randint(lo, min(lo + self.imitation_rows, buf.buffer_size), size=n)
            cols = np.random.randint(0, buf.n_envs, size=n)
            bound = 1.0 - ACTION_MARGIN
            demo = (buf.observations[rows, cols].astype(np.float32),
                    np.clip(buf.actions[rows, cols], -bound, bound).astype(np.float32))
            self._update_learning_rate(self.policy.actor_state.opt_state,
                                       learning_rate=self.lr_schedule(self._current_progress_remaining),
                                       name="learning_rate_actor")
            self._update_learning_rate(self.policy.qf_state.opt_state,
                                       learning_rate=self.initial_qf_learning_rate
                                       or self.lr_schedule(self._current_progress_remaining),
                                       name="learning_rate_critic")
            self._maybe_reset_params()
            discounts = (np.full((n,), self.gamma, dtype=np.float32) if getattr(data, "discounts", None) is None
                         else data.discounts.numpy().flatten())
            samples = ReplayBufferSamplesNp(data.observations.numpy(), data.actions.numpy(),
                                            data.next_observations.numpy(), data.dones.numpy().flatten(),
                                            data.rewards.numpy().flatten(), discounts)
            (self.policy.qf_state, self.policy.actor_state, self.ent_coef_state, self.key,
             (actor_loss, qf_loss, ent_loss, ent_value)) = self._train_imitating(
                self.tau, self.target_entropy, gradient_steps, samples, demo, jnp.float32(self.imitation_weight),
                self.policy.qf_state, self.policy.actor_state, self.ent_coef_state, self.key)
            self._n_updates += gradient_steps
            self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
            self.logger.record("train/actor_loss", actor_loss.item())
            self.logger.record("train/critic_loss", qf_loss.item())
            self.logger.record("train/ent_coef_loss", ent_loss.item())
            self.logger.record("train/ent_coef", ent_value.item())

        @classmethod
        @partial(jax.jit, static_argnames=["cls", "gradient_steps"])
        def _train_imitating(cls, tau, target_entropy, gradient_steps: int, data, demo, weight, qf_state,
                             actor_state, ent_coef_state, key) -> Any:
            """sbx's update loop (critic, soft update, actor and temperature at every step) with the
            demonstrations' batch beside the replay batch."""
            bs = data.observations.shape[0] // gradient_steps

            def one(i, carry):
                qf_state, actor_state, ent_coef_state, key, _ = carry
                b = type(data)(*(jax.lax.dynamic_slice_in_dim(x, i * bs, bs) for x in data))
                d_obs, d_act = (jax.lax.dynamic_slice_in_dim(x, i * bs, bs) for x in demo)
                qf_state, (qf_loss, ent_value), key = cls.update_critic(
                    actor_state, qf_state, ent_coef_state, b.observations, b.actions, b.next_observations,
                    b.rewards, b.dones, b.discounts, key)
                qf_state = cls.soft_update(tau, qf_state)
                actor_state, actor_loss, key, entropy = update_actor(actor_state, qf_state, ent_coef_state,
                                                                     b.observations, d_obs, d_act, weight, key)
                ent_coef_state, ent_loss = cls.update_temperature(target_entropy, ent_coef_state, entropy)
                return qf_state, actor_state, ent_coef_state, key, (actor_loss, qf_loss, ent_loss, ent_value)

            z = jnp.array(0.0)
            qf_state, actor_state, ent_coef_state, key, info = jax.lax.fori_loop(
                0, gradient_steps, one, (qf_state, actor_state, ent_coef_state, key, (z, z, z, z)))
            return qf_state, actor_state, ent_coef_state, key, info

    ImitatingSAC.__module__ = __name__
    ImitatingSAC.__qualname__ = "ImitatingSAC"
    _ImitatingSAC = ImitatingSAC
    return ImitatingSAC
