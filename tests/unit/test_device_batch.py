"""``n_envs: auto``: the batch each device gets (`agents.common.device_batch`)
with fake devices."""

from __future__ import annotations

import pytest
import yaml

from agents.common.config import (
    APGConfig,
    PPOConfig,
    load_apg_config,
    load_ppo_config,
    load_trainer_config_and_choice,
    trainer_config_and_choice,
)
from agents.common.device_batch import (
    CPU_N_ENVS,
    Device,
    device_n_envs,
    size_for_device,
)

GIB = 2**30
CPU = Device("cpu", "cpu", None)
#: What JAX reports of an H100 and an H200: XLA's allocator may use 75%.
H100 = Device("gpu", "NVIDIA H100 80GB HBM3", int(0.75 * 79.6 * GIB))
H200 = Device("gpu", "NVIDIA H200", int(0.75 * 139.8 * GIB))


def test_the_cpu_keeps_64_and_the_config_as_written() -> None:
    assert device_n_envs(CPU) == CPU_N_ENVS == 64
    data = yaml.safe_load(open_config("ppo_milan"))
    assert data["n_envs"] == "auto"
    sized, choice = size_for_device(PPOConfig, data, CPU)
    assert sized == {**data, "n_envs": 64}
    assert choice.n_envs == 64 and choice.changed == {}


def test_auto_on_this_machine_is_the_old_number() -> None:
    """The tests run on a CPU: the built-in configs are what they were."""
    cfg, choice = load_trainer_config_and_choice(PPOConfig, "ppo_milan")
    assert cfg.n_envs == 64 and choice is not None and choice.n_envs == 64
    assert (cfg.total_env_steps, cfg.lr, cfg.minibatches) == (1048576, 0.001, 4)
    assert cfg.num_updates == 256
    assert load_apg_config("apg_milan").n_envs == 64
    assert load_apg_config("apg_milan").total_env_steps == 196608
    numbered, none = trainer_config_and_choice(PPOConfig, {**cfg.to_dict()})
    assert numbered == cfg and none is None  # a number is kept, no choice


def test_an_h100_class_gpu_gets_4096_and_as_many_updates() -> None:
    assert device_n_envs(H100) == 4096
    assert device_n_envs(H200) == 8192
    data = yaml.safe_load(open_config("ppo_milan"))
    sized, choice = size_for_device(PPOConfig, data, H100)
    cfg = PPOConfig(**{**PPOConfig().to_dict(), **sized}).replace()
    assert cfg.n_envs == 4096
    assert cfg.num_updates == load_ppo_config("ppo_milan").num_updates == 256
    assert cfg.total_env_steps == 256 * 4096 * 64 == 67_108_864
    assert cfg.minibatches == 32  # 8x the CPU's, each minibatch 8x larger
    assert cfg.lr == pytest.approx(0.001 * 8**0.5)
    assert "4096 roundabouts" in choice.describe() and "H100" in choice.describe()
    assert choice.to_dict()["device"]["kind"] == H100.kind


def test_the_rule_reads_memory_then_kind_then_a_fallback() -> None:
    assert device_n_envs(Device("gpu", "NVIDIA A100-SXM4-40GB", 30 * GIB)) == 2048
    assert device_n_envs(Device("gpu", "NVIDIA H100", None)) == 4096  # by kind
    assert device_n_envs(Device("gpu", "Some GPU", None)) == 1024  # 12 GiB
    assert device_n_envs(Device("gpu", "tiny", 1 * GIB)) == 256  # the floor
    assert device_n_envs(Device("tpu", "TPU v4", 30 * GIB, count=4)) == 4 * 2048
    assert device_n_envs(Device("gpu", "huge", 4096 * GIB)) == 8192  # the cap


def test_apg_keeps_its_learning_rate() -> None:
    data = yaml.safe_load(open_config("apg_milan"))
    sized, choice = size_for_device(APGConfig, data, H100)
    assert sized["n_envs"] == 4096 and "lr" not in choice.changed
    assert sized["total_env_steps"] == 96 * 4096 * 32


def open_config(name: str) -> str:
    from importlib import resources

    return resources.files("configs").joinpath(f"{name}.yaml").read_text()
