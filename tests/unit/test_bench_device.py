"""The batches `jaxround bench` times on each device
(`jaxround.apps.bench.device`), with fake devices."""

from __future__ import annotations

from jaxround.apps.bench.device import device_batches, largest_batch, policy_batch
from tests.unit.test_device_batch import CPU, H100, H200


def test_the_benchmark_batches_grow_with_the_device() -> None:
    assert device_batches(CPU) == (1, 16, 256, 1024, 4096)
    assert policy_batch(CPU) == 256
    assert largest_batch(H100) == 32768
    assert device_batches(H200)[-1] == 65536
    assert device_batches(H200)[5:] == (8192, 16384, 32768, 65536)
    assert policy_batch(H200) == 16384


def test_the_device_check_runs_each_step_within_its_limit(tmp_path) -> None:
    import sys

    from jaxround.apps.bench import device_check

    steps = device_check.check_steps(tmp_path)
    assert [s[0] for s in steps] == ["bench", "run"]
    assert sum(s[2] for s in steps) < 8 * 60
    assert "--json" in steps[0][1] and "--quick" in steps[1][1]
    ok = device_check.run_step(
        "bench", [sys.executable, "-c", "print('{}')"], 30, tmp_path / "b.json"
    )
    assert ok["exit_status"] == 0 and (tmp_path / "b.json").read_text() == "{}\n"
    slow = device_check.run_step(
        "run", [sys.executable, "-c", "import time; time.sleep(5)"], 1, None
    )
    assert slow["exit_status"] is None and slow["seconds"] < 5


def test_the_device_check_reads_the_bench_json_after_stray_lines() -> None:
    import json

    from jaxround.apps.bench.device_check import _json_document

    # libsumo warns on stdout in every SUMO worker beside another pyarrow
    stdout = (
        "Warning! pyarrow is installed\n Try to uninstall\n"
        '{\n "device": {"kind": "H100"}\n}\n'
    )
    assert json.loads(_json_document(stdout)) == {"device": {"kind": "H100"}}
    assert _json_document("no document") == "no document"
