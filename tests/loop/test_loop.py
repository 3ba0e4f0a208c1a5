"""loop.py on its own: the blocks a run drives, in order, what it logs and when it evaluates,
read off the session's tiny two-phase R2PAC run (2 lanes, 20 critic + 20 actor steps, blocks of
10, evaluation every 10 steps)."""
import json

from r2pac_jax.agents import make_agent
from r2pac_jax.config import make_config
from r2pac_jax.tasks import get_task


def _rows(path):
    return [json.loads(x) for x in path.read_text().splitlines()]


def test_blocks_run_in_schedule_order_one_row_per_lane(tiny_run):
    rows = _rows(tiny_run["run"] / "metrics.jsonl")
    assert [(r["phase"], r["step"], r["lane"]) for r in rows] == [
        ("critic", 10, 0), ("critic", 10, 1), ("critic", 20, 0), ("critic", 20, 1),
        ("actor", 30, 0), ("actor", 30, 1), ("actor", 40, 0), ("actor", 40, 1)]


def test_no_evaluation_before_the_agent_has_a_policy(tiny_run):
    """R2PAC's critic phase trains no policy (its unevaluated_phases): the evaluations are the
    actor phase's blocks only, every lane each time, and the last is the final policy's."""
    ev = _rows(tiny_run["run"] / "eval.jsonl")
    assert [(r["step"], r["lane"]) for r in ev] == [(30, 0), (30, 1), (40, 0), (40, 1)]
    res = json.loads((tiny_run["run"] / "results.json").read_text())
    final = [r["normalized_reward"] for r in ev if r["step"] == 40]
    assert res["normalized_reward"]["per_seed"] == final


def test_phase_and_progress_knowledge_lives_in_the_agent():
    task = get_task("ReachAvoid")
    r2pac = make_agent(make_config(task, "r2pac", "quick", {}), task.obs_dim, task.act_dim)
    assert r2pac.unevaluated_phases == ("critic",)
    assert r2pac.progress_metrics == {"l": "threshold"}
    bc = make_agent(make_config(task, "bc-all-mlp", "quick", {}), task.obs_dim, task.act_dim)
    assert bc.unevaluated_phases == () and bc.progress_metrics == {}
