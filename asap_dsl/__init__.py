"""asap-dsl: specify control tasks to fulfil as soon as possible, and compile them.

    import asap_dsl
    prog = asap_dsl.load("specs/dc_motor.asap")
    prog.system.state_names           # ('theta', 'omega', 'i')
    prog.task("reach").spec.robustness(traces)
"""

from .diagnostics import Diagnostic, SpecError
from .program import Formula, Program, Task, load, loads

__version__ = "0.1.0"

__all__ = ["Diagnostic", "Formula", "Program", "SpecError", "Task", "evaluate", "load", "loads", "make_env",
           "make_vec_env", "train", "__version__"]


def __getattr__(name):  # lazy: gymnasium, stable-baselines3 and torch load only when needed
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
