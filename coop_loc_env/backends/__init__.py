"""Estimator registry: estimator name -> backend class, and the ``extras`` it declares.

The single source of the estimator names a config accepts
(``ScenarioConfig.estimator``, ``RobotSpec.estimator``) and of the ``extras`` keys
(:mod:`coop_loc_env.extras`). It imports no backend: the shipped ones are listed
by ``"module:attr"`` path and imported when a team first uses them (their options
when a config's ``extras`` is checked), so that config validation causes no import
circle. A backend from outside the package registers with :func:`register_backend`.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any

from coop_loc_env.extras import NO_OPTIONS, BackendOptions

#: The estimators shipped with the package.
BUILTIN_ESTIMATORS = ("ekf", "mcl", "mle")

#: Estimator name -> backend class, or ``"module:Class"`` imported on first use.
BACKENDS: dict[str, type | str] = {
    "ekf": "coop_loc_env.backends.ekf:EKFBackend",
    "mcl": "coop_loc_env.backends.mcl:MCLBackend",
    "mle": "coop_loc_env.backends.mle:MLEBackend",
}

#: Estimator name -> its :class:`~coop_loc_env.extras.BackendOptions` (or a
#: ``"module:attr"`` path to them), where given apart from the class; a backend
#: without an entry here declares them as its class attribute ``options``.
BACKEND_OPTIONS: dict[str, BackendOptions | str] = {
    "ekf": NO_OPTIONS,
    "mcl": "coop_loc_env.backends.mcl_options:MCL_OPTIONS",
    "mle": "coop_loc_env.backends.mle_options:MLE_OPTIONS",
}


def _load(path: str) -> Any:
    module, _, attr = path.partition(":")
    return getattr(importlib.import_module(module), attr)


def register_backend(name: str, cls: type | str | None = None,
                     options: BackendOptions | str | None = None) -> Any:
    """Make a backend class available as estimator ``name``.

    ``cls`` is an :class:`~coop_loc_env.backends.base.EstimatorBackend` subclass or a
    ``"module:Class"`` path imported when a team first uses ``name``. Its ``extras``
    keys are ``options`` if given, else the class attribute ``options`` (none by
    default). Without ``cls``, a class decorator::

        from coop_loc_env.backends.ekf import EKFBackend
        from coop_loc_env.extras import BackendOptions, is_number, option

        @register_backend("slow_ekf")
        class SlowEKF(EKFBackend):
            options = BackendOptions({"slow_gain": option(is_number, "a number")})

        env = coop_loc_env.parallel_env(estimator="slow_ekf", extras={"slow_gain": 0.5})
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"an estimator name must be a non-empty string, got {name!r}")

    def register(klass: type | str) -> type | str:
        BACKENDS[name] = klass
        if options is None:
            BACKEND_OPTIONS.pop(name, None)
        else:
            BACKEND_OPTIONS[name] = options
        return klass

    return register if cls is None else register(cls)


def estimator_names() -> tuple[str, ...]:
    """The registered estimator names, sorted."""
    return tuple(sorted(BACKENDS))


def check_estimator(key: str, name: Any) -> None:
    """Raise ``ValueError`` naming ``key`` unless ``name`` is a registered estimator."""
    if not isinstance(name, str) or name not in BACKENDS:
        raise ValueError(f"{key} must be a registered estimator "
                         f"({', '.join(estimator_names())}), got {name!r}")


def backend_class(name: str) -> type:
    """The backend class registered as ``name`` (``ValueError`` if there is none)."""
    if name not in BACKENDS:
        raise ValueError(
            f"estimator {name!r} is not available; available: {', '.join(sorted(BACKENDS))}"
        )
    cls = BACKENDS[name]
    if isinstance(cls, str):
        cls = BACKENDS[name] = _load(cls)
    return cls


def backend_options(name: str) -> BackendOptions:
    """The ``extras`` options estimator ``name`` declares."""
    opts = BACKEND_OPTIONS.get(name)
    if opts is None:
        return getattr(backend_class(name), "options", NO_OPTIONS)
    if isinstance(opts, str):
        opts = BACKEND_OPTIONS[name] = _load(opts)
    return opts


def extras_schema() -> dict[str, BackendOptions]:
    """Every declared ``extras`` key -> the options that declare it (all backends)."""
    schema: dict[str, BackendOptions] = {}
    for name in BACKENDS:
        opts = backend_options(name)
        for key in opts.checks:
            schema.setdefault(key, opts)
    return schema


def validate_extras(cfg: Any) -> None:
    """Check ``cfg.extras`` against the registered backends' options: ``ValueError``
    naming the key on an undeclared key or a bad value."""
    extras = cfg.extras
    if not isinstance(extras, Mapping):
        raise ValueError(f"extras must be a dict, got {extras!r}")
    if not extras:
        return
    schema = extras_schema()
    used: dict[int, BackendOptions] = {}
    for key, value in extras.items():
        if key not in schema:
            raise ValueError(
                f"unknown extras key {key!r}; known keys: {', '.join(sorted(schema))}"
            )
        schema[key].check(key, value)
        used[id(schema[key])] = schema[key]
    for opts in used.values():
        if opts.check_config is not None:
            opts.check_config(cfg)
