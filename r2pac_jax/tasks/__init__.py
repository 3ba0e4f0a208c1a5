"""The tasks: the registry (`tasks/registry.py`) and the families that register their tasks, one
record each (`demo`, `navigation`, `velocity`, `bullet`; their simulators are imported only when
an environment is made)."""
# isort: off  (the families register in this order: the order of `TASKS`)
from r2pac_jax.tasks import demo, navigation, velocity, bullet  # noqa: F401
# isort: on
from r2pac_jax.tasks.registry import (PHYSICS, TASKS, CollectionSpec,  # noqa: F401 (the API)
                                      EnvUnavailableError, TaskSpec, UnknownPhysicsError,
                                      UnknownTaskError, _ALIASES, get_task, lazy_env, list_tasks,
                                      register, set_collection, set_env_factory)
