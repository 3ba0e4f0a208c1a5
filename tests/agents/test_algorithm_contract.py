"""The algorithm-module contract (agents.AlgorithmSpec): every registered module meets it, and a
module that breaks it is refused naming what is missing or of the wrong kind."""
import pytest


def test_every_algorithm_module_meets_the_contract():
    import types

    from r2pac_jax.agents import AlgorithmSpec, MODULES, algorithm_spec

    for m in MODULES:
        spec = algorithm_spec(__import__(f"r2pac_jax.agents.{m}", fromlist=["_"]))
        assert isinstance(spec, AlgorithmSpec) and spec.VARIANTS
    broken = types.ModuleType("broken")
    broken.CONFIG, broken.PRESETS, broken.VARIANTS = dict, {}, ["not", "a", "dict"]
    with pytest.raises(TypeError, match=r"missing FIXED, FIXED_WHY, HPARAMS, Agent, "
                                        r"check_hparams, phases, task_values, validate; "
                                        r"wrong kind: VARIANTS \(want dict\)"):
        algorithm_spec(broken)
