"""The algorithm-module contract (agents.AlgorithmSpec): every registered module's SPEC meets
it, and a module or spec that breaks it is refused naming what is wrong."""
import types

import pytest

from r2pac_jax.agents import MODULES, AlgorithmSpec, algorithm_spec


def test_every_algorithm_module_meets_the_contract():
    for m in MODULES:
        spec = algorithm_spec(__import__(f"r2pac_jax.agents.{m}", fromlist=["_"]))
        assert isinstance(spec, AlgorithmSpec) and spec.VARIANTS


def test_a_module_without_a_spec_or_a_spec_of_the_wrong_kinds_is_refused():
    broken = types.ModuleType("broken")
    broken.CONFIG, broken.VARIANTS = dict, {}  # loose names are not the contract
    with pytest.raises(TypeError, match="algorithm module broken breaks the contract: it has no "
                                        "SPEC"):
        algorithm_spec(broken)
    good = algorithm_spec(__import__("r2pac_jax.agents.bc_mlp", fromlist=["_"]))
    fields = {f: getattr(good, f) for f in AlgorithmSpec.__dataclass_fields__}
    with pytest.raises(TypeError, match=r"wrong kind: VARIANTS \(want dict\), Agent \(want type\)"):
        AlgorithmSpec(**dict(fields, VARIANTS=["not", "a", "dict"], Agent="Agent"))
    with pytest.raises(TypeError, match="missing 1 required positional argument: 'validate'"):
        AlgorithmSpec(**{k: v for k, v in fields.items() if k != "validate"})
