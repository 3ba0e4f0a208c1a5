"""One error base: every user-facing error derives from R2pacError (and keeps its builtin), and
each command line turns any R2pacError into its one line and exit 2."""
import pytest

from r2pac_jax.errors import R2pacError


def _classes():
    from r2pac_jax.checkpoint import CheckpointDamaged, CheckpointUnreadable
    from r2pac_jax.config import ConfigError
    from r2pac_jax.data.chunks import ChunkError
    from r2pac_jax.data.dsrl import DatasetError
    from r2pac_jax.data.factory import FactoryError
    from r2pac_jax.envs.base import ActionError, BackendUnavailableError
    from r2pac_jax.envs.gym import ResetNeeded
    from r2pac_jax.io import DirectoryBusy, ForeignDirectory, WriteError
    from r2pac_jax.loop import TrainingDiverged
    from r2pac_jax.memory import MemoryShortfall
    from r2pac_jax.sweep import SweepError
    from r2pac_jax.tasks import EnvUnavailableError, UnknownPhysicsError, UnknownTaskError

    return [(ConfigError, ValueError), (CheckpointUnreadable, ValueError),
            (CheckpointDamaged, ValueError), (MemoryShortfall, ValueError),
            (ChunkError, ValueError), (DatasetError, ValueError), (FactoryError, ValueError),
            (ActionError, ValueError), (BackendUnavailableError, RuntimeError),
            (ResetNeeded, RuntimeError), (DirectoryBusy, RuntimeError), (WriteError, OSError),
            (ForeignDirectory, OSError), (TrainingDiverged, RuntimeError),
            (SweepError, ValueError), (EnvUnavailableError, RuntimeError),
            (UnknownPhysicsError, RuntimeError), (UnknownTaskError, KeyError)]


@pytest.mark.parametrize("cls,builtin", _classes(), ids=lambda c: getattr(c, "__name__", ""))
def test_user_facing_errors_share_one_base(cls, builtin):
    assert issubclass(cls, R2pacError) and issubclass(cls, builtin)


class _Novel(R2pacError):
    """An error type no command line names: the base alone must catch it."""


def _raise(*_, **__):
    raise _Novel("the problem, and the fix")


def _cli_cases(monkeypatch, tmp_path):
    import r2pac_jax.data as data
    import r2pac_jax.data.factory as factory
    import r2pac_jax.evaluate as evaluate
    import r2pac_jax.sweep as sweep

    monkeypatch.setattr(data, "load_task_dataset", _raise)
    monkeypatch.setattr(factory, "generate_dataset", _raise)
    monkeypatch.setattr(sweep, "run_sweep", _raise)
    monkeypatch.setattr(evaluate, "evaluate_run", _raise)
    monkeypatch.setattr(evaluate, "selection_rules", lambda *_: ())
    from r2pac_jax import table, train
    from r2pac_jax.data.__main__ import main as data_main

    # table binds the name at import (JAX-free imports sit at its top): patched where it is used
    monkeypatch.setattr(table, "load_task_dataset", _raise)

    spec = tmp_path / "s.json"
    spec.write_text("{}")
    return [
        (train.main, ["--task", "ReachAvoid", "--out", str(tmp_path / "t"), "--no-progress"]),
        (table.main, ["--tasks", "ReachAvoid", "--algos", "bc-all-mlp", "--out",
                      str(tmp_path / "tb"), "--no-progress"]),
        (sweep.main, [str(spec), "--out", str(tmp_path / "sw"), "--no-progress"]),
        (evaluate.main, [str(tmp_path)]),
        (data_main, ["make", "--task", "ReachAvoid"]),
    ]


def test_every_cli_turns_the_base_into_one_line(monkeypatch, tmp_path, capsys):
    for main, argv in _cli_cases(monkeypatch, tmp_path):
        rc = main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2, (main.__module__, err)
        assert err[-1] == "error: the problem, and the fix", (main.__module__, err)

