"""experiments/table1/paper_compare.py: the paper's Table 1 beside ours, cell by cell."""
import csv

import pytest

from conftest import load_script

# Two rows in the paper's tab-separated layout (columns BC CDT CPQ COptiDICE TREBI FISOR ours);
# the header and average rows must be skipped, "AntVel" mapped to our task name.
PAPER = "\n".join([
    "Table 1: Normalized DSRL (Liu et al., 2023a) benchmark results.",
    "",
    "\tBC\t\tCDT\t\tCPQ\t\tCOptiDICE\t\tTREBI\t\tFISOR\t\tours\t",
    "Task" + "\treward\tcost" * 7,
    "CarRun\t0.97\t0.33\t0.99\t0.65\t0.85\t0.00\t0.93\t0.00\t0.97\t0.23\t0.73\t0.14\t0.95\t0.80",
    "AntVel\t0.85\t16.21\t0.98\t0.91\t-1.01\t0.00\t1.00\t3.28\t0.31\t0.00\t0.89\t0.00\t0.90\t0.58",
    "Average\t0.1\t0.2\t0.1\t0.2\t0.1\t0.2\t0.1\t0.2\t0.1\t0.2\t0.1\t0.2\t0.1\t0.2",
])


@pytest.fixture(scope="module")
def pc():
    return load_script("experiments/table1/paper_compare.py")


def _table(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, ["task", "family", "algo", "reward_mean", "reward_std", "cost_mean",
                               "cost_std", "safe", "seeds"])
        w.writeheader()
        for task, algo, r, c in rows:
            w.writerow(dict(task=task, family="x", algo=algo, reward_mean=r, reward_std=0,
                            cost_mean=c, cost_std=0, safe=(c is not None and c < 1), seeds=3))


def test_paper_rows_are_parsed_from_the_text_and_renamed(pc, tmp_path):
    p = tmp_path / "paper.txt"
    p.write_text(PAPER)
    t = pc.paper_table(p)
    assert set(t) == {"CarRun", "AntVelocity"}
    assert t["CarRun"]["CDT"] == (0.99, 0.65) and t["AntVelocity"]["ours"] == (0.90, 0.58)


def test_a_text_without_table_1_rows_is_refused(pc, tmp_path):
    p = tmp_path / "paper.txt"
    p.write_text("Table 1: Normalized DSRL\nnothing here\n")
    with pytest.raises(SystemExit, match="no Table-1 rows"):
        pc.paper_table(p)


def test_cells_not_run_show_a_dash_and_do_not_count_in_the_verdict(pc, tmp_path):
    paper = tmp_path / "paper.txt"
    paper.write_text(PAPER)
    ours = tmp_path / "table.csv"
    # CarRun: CDT safe (paper safe: agrees), R2PAC unsafe (paper safe: disagrees);
    # AntVelocity: CDT not run (an empty cell, as the table writes it), R2PAC safe (agrees);
    # OurTask is not in the paper.
    _table(ours, [("CarRun", "cdt", 0.9, 0.1), ("CarRun", "r2pac", 0.5, 2.0),
                  ("AntVelocity", "cdt", "", None), ("AntVelocity", "r2pac", 0.7, 0.2),
                  ("OurTask", "r2pac", 0.1, 0.0)])
    out = pc.compare(pc.paper_table(paper), pc.our_table(ours))
    lines = out.splitlines()
    assert lines[0] == "| Task | CDT: paper | CDT: here | R2PAC: paper | R2PAC: here |"
    ant = next(x for x in lines if x.startswith("| AntVelocity"))
    assert ant == "| AntVelocity | **0.98 / 0.91** | – | **0.90 / 0.58** | **0.70 / 0.20** |"
    car = next(x for x in lines if x.startswith("| CarRun"))
    assert car.endswith("| **0.95 / 0.80** | 0.50 / 2.00 † |")
    assert "the same in 2 of 3 cells" in out
    assert "outside the paper's table: OurTask" in out
    assert out.endswith("Every task of the paper's table has a row here.")
    # a paper task without a row of ours is named
    _table(ours, [("CarRun", "cdt", 0.9, 0.1)])
    out = pc.compare(pc.paper_table(paper), pc.our_table(ours))
    assert out.endswith("Paper tasks without a row here: AntVelocity.")
