"""`legws optimize --all`: a local process pool, and a Dask LocalCluster on loopback."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from legws_daemon.cli.main import run
from tests.net import free_port


def read_index(root: Path) -> list[dict[str, object]]:
    return list(json.loads((root / "index.json").read_text()))


@pytest.mark.slow  # eight optimisation runs on a process pool: ~20 s
def test_all_on_a_process_pool(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    args = ["optimize", "--all", "--scene", "breakfast_easy,desk", "--seeds", "0,1",
            "--iterations", "8", "--out", str(root), "--quiet", "--workers", "2"]  # fmt: skip
    assert run(args) == 0
    index = read_index(root)
    assert [(r["scene"], r["seed"]) for r in index] == [
        ("breakfast_easy", 0), ("breakfast_easy", 1), ("desk", 0), ("desk", 1),
    ]  # fmt: skip
    for name in ("breakfast_easy", "desk"):
        for seed in (0, 1):
            summary = json.loads((root / name / f"seed{seed}" / "summary.json").read_text())
            assert summary["seed"] == seed
            assert summary["scene"] == name


def test_all_on_a_dask_cluster_over_loopback(tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
        host="127.0.0.1", dashboard_address=None,
    ) as cluster:  # fmt: skip
        address = cluster.scheduler_address
        assert address.startswith("tcp://127.0.0.1:")
        root = tmp_path / "runs"
        args = ["optimize", "--all", "--scene", "breakfast_easy", "--seeds", "2",
                "--iterations", "4", "--out", str(root), "--quiet", "--dask", address,
                "--objective", "commit"]  # fmt: skip
        assert run(args) == 0
    summary = json.loads((root / "breakfast_easy" / "seed2" / "summary.json").read_text())
    local = tmp_path / "local"
    assert run(["optimize", "--scene", "breakfast_easy", "--seed", "2", "--iterations", "4",
                "--out", str(local), "--quiet", "--no-cache",
                "--objective", "commit"]) == 0  # fmt: skip
    # the cluster ran the same computation (the commit objective): same seed, same result
    mine = json.loads((local / "summary.json").read_text())
    assert summary["objective_kind"] == mine["objective_kind"] == "commit"
    assert mine["objective"] == summary["objective"]
    assert mine["commit_objective"] == summary["commit_objective"]


@pytest.mark.slow  # Dask gives up connecting after its 10 s timeout
def test_unreachable_scheduler_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("distributed")
    code = run(["optimize", "--all", "--scene", "desk", "--iterations", "2", "--quiet",
                "--dask", f"tcp://127.0.0.1:{free_port()}"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "Dask scheduler" in err


def test_seeds_and_dask_need_all(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(["optimize", "--scene", "desk", "--seeds", "1,2", "--quiet"]) == 2
    assert "--all" in capsys.readouterr().err


def test_impossible_problem_is_a_clear_error_not_a_hang(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the cluttered scene with 0.4 m clearance: eleven such discs do not fit the bounds
    text = (Path(__file__).parents[2] / "scenes" / "cluttered.toml").read_text()
    crowded = tmp_path / "cluttered.toml"
    crowded.write_text(text.replace("min_clearance = 0.12", "min_clearance = 0.4"))
    assert run(["optimize", "--scene", str(crowded), "--quiet", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "no layout exists" in err
