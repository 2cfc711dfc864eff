"""asap-dsl: specify control tasks to fulfil as soon as possible, and compile them.

    import asap_dsl
    prog = asap_dsl.load("specs/dc_motor.asap")
    prog.system.state_names           # ('theta', 'omega', 'i')
    prog.task("reach").spec.robustness(traces)
"""

__version__ = "0.1.0"

# The front end loads on first use too: `asapc` must be able to install its signal handlers before
# anything heavy is imported (a SIGTERM in the first second ends it as Ctrl-C does, exit 130).
_FRONT = {"Diagnostic": "diagnostics", "SpecError": "diagnostics", "Formula": "program", "Program": "program",
          "Task": "program", "load": "program", "loads": "program"}

__all__ = ["Diagnostic", "Formula", "Program", "SpecError", "Task", "evaluate", "load", "loads", "make_env",
           "make_vec_env", "register", "train", "__version__"]

# The benchmarks' gymnasium ids (asap/dc_motor-reach_avoid-v0, ...): registered now if gymnasium is
# loaded, else when it is (asap_dsl.registration; importing gymnasium here would cost 150 ms).
from . import registration as _registration  # noqa: E402

_registration.install()


def __getattr__(name):  # lazy: gymnasium, stable-baselines3 and torch load only when needed
    if name in _FRONT:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{_FRONT[name]}"), name)
    if name == "register":
        return _registration.register
    if name in ("make_env", "make_vec_env"):
        from . import env

        return getattr(env, name)
    if name == "train":
        from .backends.rl import train

        return train
    if name == "evaluate":
        from .backends.rl import evaluate

        return evaluate
    raise AttributeError(f"module 'asap_dsl' has no attribute '{name}'")
