"""`EnvParams` by driver class: each class's numbers, the shared body, the copies."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxround.core.params import EnvParams
from jaxround.envs.roundabout import check_driver_classes
from jaxround.scenario.config import SHARED_DRIVER_FIELDS, ConfigError, config_from_dict
from tests.conftest import builtin_dict


@pytest.fixture(scope="module")
def milan() -> tuple[object, EnvParams]:
    cfg = config_from_dict(builtin_dict("milan"))
    return cfg, EnvParams.from_config(cfg)


def test_each_class_has_its_vtype_and_the_body_is_shared(milan) -> None:
    cfg, params = milan
    hv, av = cfg.drivers.hv, cfg.drivers.av
    assert float(params.human.tau) == pytest.approx(hv.tau)
    assert float(params.av.tau) == pytest.approx(av.tau)
    assert float(params.av.accel) == pytest.approx(av.accel) != hv.accel
    for name in SHARED_DRIVER_FIELDS:
        assert float(getattr(params.vehicle, name)) == pytest.approx(getattr(hv, name))
    assert float(params.demand.penetration) == cfg.simulation.penetration
    assert params.demand.od.shape == (cfg.n_legs, cfg.n_legs)


def test_for_vehicles_gives_one_bundle_per_vehicle(milan) -> None:
    _, params = milan
    is_av = jnp.array([True, False, True])
    bundle = params.for_vehicles(is_av)
    np.testing.assert_allclose(
        bundle.tau, [params.av.tau, params.human.tau, params.av.tau]
    )
    assert jnp.ndim(bundle.length) == 0  # shared numbers stay scalars
    assert bundle.columns().tau.shape == (3, 1)
    assert float(bundle.relax_temperature) == 0.0


def test_with_human_sends_each_number_to_its_part(milan) -> None:
    _, params = milan
    fitted = params.with_human(accel=jnp.float32(2.0), decel=jnp.float32(4.0))
    assert float(fitted.human.accel) == 2.0 and float(fitted.vehicle.decel) == 4.0
    assert float(fitted.av.accel) == float(params.av.accel)  # the AVs keep theirs
    assert float(fitted.human_number("decel")) == 4.0
    assert float(fitted.human_number("accel")) == 2.0
    with pytest.raises(ValueError, match="unknown driver number.*'acel'"):
        params.with_human(acel=1.0)
    with pytest.raises(ValueError, match="unknown driver number 'penetration'"):
        params.human_number("penetration")


def test_a_batch_of_penetrations_is_traced(milan) -> None:
    _, params = milan
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (3, *jnp.shape(x))), params)
    batch = batch.with_penetration([0.0, 0.5, 1.0])
    np.testing.assert_allclose(batch.demand.penetration, [0.0, 0.5, 1.0])
    assert batch.demand.penetration.dtype == jnp.float32


def test_calibrated_shared_numbers_reach_the_avs(milan) -> None:
    cfg, _ = milan
    fitted = cfg.with_human_drivers(decel=4.0, tau=1.1)
    assert fitted.drivers.hv.decel == fitted.drivers.av.decel == 4.0
    assert fitted.drivers.av.tau == cfg.drivers.av.tau  # not shared: the AVs' own


def test_avs_with_another_body_are_refused_by_the_jax_env() -> None:
    d = builtin_dict("milan")
    d["drivers"]["av"]["length"] = 4.5
    cfg = config_from_dict(d)  # SUMO alone can run it
    with pytest.raises(ConfigError, match=r"drivers\.av\.length: 4\.5 differs"):
        check_driver_classes(cfg)  # what RoundaboutEnv checks first
