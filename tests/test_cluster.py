"""``evaluate --cluster``: the per-seed jobs on a Dask distributed cluster give exactly the local pool's results."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from lab.evaluate import evaluate
from lab.forests import ForestSpec

pytestmark = pytest.mark.shares_cores  # lockstep processes, no deadline: they may share the cores (conftest.py)

WALL_CLOCK = ("wall_time_s", "job_wall_s", "finished_unix_s", "worker_pid", "worker_rss_mb")  # where and when, not what
ROOT = Path(__file__).resolve().parents[1]


def _per_seed(out: Path) -> dict[str, dict]:
    """results.jsonl by job key, wall-clock fields dropped and the output folder replaced by a placeholder."""
    got = {}
    for line in (out / "results.jsonl").read_text().splitlines():
        r = json.loads(line.replace(str(out), "<out>"))
        for k in WALL_CLOCK:
            r.pop(k)
        got[r["key"]] = r
    return got


@pytest.mark.slow
def test_cluster_results_equal_the_local_pool(tmp_path):
    distributed = pytest.importorskip("distributed")
    kw = dict(seed0=40, spec=ForestSpec(length_m=12.0), mode="inprocess", workers=2, progress=False)
    planners, densities, n = ["safe"], [3.0], 3
    local = evaluate(planners, densities, n, out=tmp_path / "pool", **kw)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        dask = evaluate(planners, densities, n, out=tmp_path / "dask", cluster=cluster.scheduler_address, **kw)
    a, b = _per_seed(tmp_path / "pool"), _per_seed(tmp_path / "dask")
    assert len(a) == 3 and set(a) == set(b)
    for key in a:
        assert a[key] == b[key], key  # exactly: every number, class, path
    assert local["per_planner"] == dask["per_planner"]
    assert dask["cluster"] == cluster.scheduler_address and "Dask cluster at tcp://127.0.0.1" in (
        tmp_path / "dask" / "summary.md").read_text()


def test_help_lists_cluster_without_importing_dask():
    code = ("import sys\nfrom companion.cli.main import main\n"
            "try:\n    main(['evaluate', '--help'])\nexcept SystemExit:\n    pass\n"
            "print('DASK' if any(m.split('.')[0] in ('dask', 'distributed') for m in sys.modules) else 'NODASK')\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert "--cluster ADDRESS" in proc.stdout and proc.stdout.strip().endswith("NODASK")
