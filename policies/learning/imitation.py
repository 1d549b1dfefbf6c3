"""Behaviour cloning: warm-start a stable-baselines3 actor-critic from a scripted teacher.

:func:`collect_demonstrations` runs a teacher policy (e.g. ``wander``,
:class:`policies.scripted.wander.WanderPolicy`) on seeded episodes of the training env and
records, per robot and step, the robot's observation, the teacher's action
and the reward the training env pays (:class:`policies.learning.vec_env.TimeToLocalizeReward`
when ``reward_mode="localize"``). :func:`behaviour_clone` then fits an SB3
``ActorCriticPolicy`` (PPO's) to them with torch:

* the actor's action *mean* by mean squared error against the teacher's action
  (clipped to the action box; for a Gaussian policy with a fixed standard
  deviation this is maximum likelihood);
* the critic to the teacher's discounted returns under the training reward
  (Monte Carlo, ``gamma`` of the PPO run; an episode cut at ``max_cycles``
  gets the tail its last reward would earn if repeated forever), so that PPO
  fine-tuning starts with a value function that already knows the task
  rather than one that drags the cloned actor off while it learns;
* the Gaussian's ``log_std`` set to ``log_std`` (exploration noise of the
  fine-tuning);
* optionally DAgger rounds (Ross, Gordon & Bagnell 2011): the clone drives,
  the teacher labels the states the clone visits, and the clone is refitted on
  all the labels so far, which corrects the drift of a clone off the
  teacher's states.

The teacher is stochastic (the wander policy adds turning noise); the clone
learns its mean action.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

__all__ = ["behaviour_clone", "collect_demonstrations", "make_teacher", "discounted_returns",
           "stack_observations", "concat_observations"]


def stack_observations(items: list):
    """Stack per-agent observations into a batch: an array, or (``obs_format="dict"``) a
    dict of arrays, one per key."""
    if items and isinstance(items[0], dict):
        return {k: np.stack([np.asarray(o[k], dtype=np.float32) for o in items])
                for k in items[0]}
    return np.stack(items).astype(np.float32)


def concat_observations(batches: list):
    """Join observation batches (arrays, or dicts of arrays) along the first axis."""
    if batches and isinstance(batches[0], dict):
        return {k: np.concatenate([b[k] for b in batches]) for k in batches[0]}
    return np.concatenate(batches).astype(np.float32)


def make_teacher(spec: str):
    """A teacher policy: ``wander`` or ``wander:SPEED``
    (:class:`policies.scripted.wander.WanderPolicy`), or any spec of
    :func:`policies.learning.loader.make_policy` (a registered policy name)."""
    name, _, arg = str(spec).partition(":")
    if name == "wander":
        from policies.scripted.wander import WanderPolicy

        if not arg:
            return WanderPolicy()
        try:
            speed = float(arg)
        except ValueError as err:
            raise ValueError(f"teacher {spec!r}: speed must be a number") from err
        return WanderPolicy(speed)
    if arg:
        raise ValueError(f"teacher {spec!r}: only wander takes an argument (wander:SPEED)")
    from policies.learning.loader import make_policy

    return make_policy(spec)


def discounted_returns(rewards: np.ndarray, gamma: float, truncated: bool) -> np.ndarray:
    """Discounted return from each step of one robot's reward sequence ``(T,)``.

    ``truncated`` (the episode was cut by the time limit) adds the tail of the
    last reward repeated forever, ``gamma**(T - t) * r_last / (1 - gamma)``.
    """
    rewards = np.asarray(rewards, dtype=float)
    out = np.zeros_like(rewards)
    acc = rewards[-1] / (1.0 - gamma) if (truncated and len(rewards) and gamma < 1) else 0.0
    for t in range(len(rewards) - 1, -1, -1):
        acc = rewards[t] + gamma * acc
        out[t] = acc
    return out


def collect_demonstrations(
    env_fn,
    teacher,
    n_episodes: int,
    seed: int,
    gamma: float = 0.99,
    actor=None,
) -> dict[str, Any]:
    """Run ``teacher`` for ``n_episodes`` episodes (seeds ``seed + k``) of ``env_fn()``.

    ``env_fn`` builds the training env (possibly reward-wrapped; see
    :func:`policies.learning.vec_env.make_env_fn`). With ``actor`` (a function of the
    stacked observations of the live agents returning their actions) the
    actor drives and the teacher only labels the states it visits (DAgger).
    Returns ``obs (N, d)``, ``actions (N, 2)`` (clipped to ``[-1, 1]``),
    ``returns (N,)`` (discounted, per robot), ``episodes``, ``steps`` (team steps) and ``wall_s``.
    """
    if isinstance(n_episodes, bool) or not isinstance(n_episodes, int) or n_episodes < 1:
        raise ValueError(f"n_episodes must be a positive integer, got {n_episodes!r}")
    if not 0 < gamma <= 1:
        raise ValueError(f"gamma must be in (0, 1], got {gamma!r}")
    start = time.perf_counter()
    env = env_fn()
    obs_all, act_all, ret_all = [], [], []
    steps = 0
    try:
        for k in range(n_episodes):
            obs, _ = env.reset(seed=seed + k)
            inner = getattr(env, "unwrapped", env)  # the teacher reads the unwrapped env
            teacher.reset(inner, seed=seed + k)
            per_agent: dict[str, dict[str, list]] = {
                a: {"obs": [], "act": [], "rew": []} for a in env.possible_agents
            }
            truncated: dict[str, bool] = {}
            while env.agents:
                actions = teacher.act(obs)
                for a in env.agents:
                    per_agent[a]["obs"].append(obs[a])  # float32 once stacked
                    per_agent[a]["act"].append(np.clip(np.asarray(actions[a], float), -1, 1))
                if actor is not None:
                    live = list(env.agents)
                    driven = np.clip(np.asarray(actor(stack_observations([obs[a] for a in live])),
                                                dtype=np.float32).reshape(len(live), -1), -1, 1)
                    actions = dict(zip(live, driven, strict=True))
                obs, rewards, terms, truncs, _ = env.step(actions)
                steps += 1
                for a, r in rewards.items():
                    per_agent[a]["rew"].append(float(r))
                    if terms[a] or truncs[a]:
                        truncated[a] = bool(truncs[a] and not terms[a])
            for a, rec in per_agent.items():
                if not rec["rew"]:
                    continue
                obs_all.append(stack_observations(rec["obs"]))
                act_all.append(np.stack(rec["act"]))
                ret_all.append(discounted_returns(np.array(rec["rew"]), gamma,
                                                  truncated.get(a, True)))
    finally:
        env.close()
    return {
        "obs": concat_observations(obs_all),
        "actions": np.concatenate(act_all).astype(np.float32),
        "returns": np.concatenate(ret_all).astype(np.float32),
        "episodes": n_episodes,
        "steps": steps,
        "wall_s": time.perf_counter() - start,
    }


def behaviour_clone(
    model,
    demos: dict[str, Any],
    epochs: int = 30,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    log_std: float = -1.0,
    value: bool = True,
    seed: int = 0,
) -> dict[str, float]:
    """Fit ``model.policy`` (an SB3 ``ActorCriticPolicy``) to ``demos`` in place.

    Returns ``action_mse`` and ``value_mse`` of the last epoch (on the whole
    set), ``epochs``, ``samples`` and ``wall_s``.
    """
    import torch

    if isinstance(epochs, bool) or not isinstance(epochs, int) or epochs < 1:
        raise ValueError(f"epochs must be a positive integer, got {epochs!r}")
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer, got {batch_size!r}")
    policy = model.policy
    for attr in ("mlp_extractor", "action_net", "value_net", "log_std"):
        if not hasattr(policy, attr):
            raise ValueError(f"behaviour_clone needs an actor-critic policy (PPO/A2C), "
                             f"{type(policy).__name__} has no {attr!r}")
    start = time.perf_counter()
    raw = demos["obs"]
    if isinstance(raw, dict):  # obs_format="dict": one tensor per key
        obs = {k: torch.as_tensor(v, dtype=torch.float32) for k, v in raw.items()}
        sizes = {len(v) for v in obs.values()}
        shape = {k: tuple(v.shape) for k, v in obs.items()}
    else:
        obs = torch.as_tensor(raw, dtype=torch.float32)
        sizes, shape = {len(obs)}, tuple(obs.shape)
    act = torch.as_tensor(demos["actions"], dtype=torch.float32)
    ret = torch.as_tensor(demos["returns"], dtype=torch.float32)
    n = len(act)
    if n == 0 or sizes != {n} or act.shape != (n, policy.action_space.shape[0]) or \
            ret.shape != (n,):
        raise ValueError(f"demos do not match: obs {shape}, actions "
                         f"{tuple(act.shape)}, returns {tuple(ret.shape)}")

    def rows(idx):
        return {k: v[idx] for k, v in obs.items()} if isinstance(obs, dict) else obs[idx]

    params = [p for name, p in policy.named_parameters() if name != "log_std"]
    opt = torch.optim.Adam(params, lr=learning_rate)
    gen = torch.Generator().manual_seed(int(seed))
    policy.set_training_mode(True)

    def forward(x):
        features = policy.extract_features(x)
        if policy.share_features_extractor:
            latent_pi, latent_vf = policy.mlp_extractor(features)
        else:
            pi_f, vf_f = features
            latent_pi = policy.mlp_extractor.forward_actor(pi_f)
            latent_vf = policy.mlp_extractor.forward_critic(vf_f)
        return policy.action_net(latent_pi), policy.value_net(latent_vf).squeeze(-1)

    for _ in range(epochs):
        perm = torch.randperm(n, generator=gen)
        for i in range(0, n, batch_size):
            idx = perm[i : i + batch_size]
            mean, v = forward(rows(idx))
            loss = torch.mean((mean - act[idx]) ** 2)
            if value:
                loss = loss + torch.mean((v - ret[idx]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
    policy.set_training_mode(False)
    with torch.no_grad():
        policy.log_std.fill_(float(log_std))
        mean, v = forward(obs)
        a_mse = float(torch.mean((mean - act) ** 2))
        v_mse = float(torch.mean((v - ret) ** 2))
    return {"action_mse": a_mse, "value_mse": v_mse, "epochs": epochs, "samples": n,
            "wall_s": time.perf_counter() - start}
