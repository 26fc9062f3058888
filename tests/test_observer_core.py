"""The observer in the compiled core (soilocp._core.ObserverCore, behind
soilocp.estimation.observer_bank.ObserverBank) against the tests' references (tests/reference_observer.py:
filterpy's KalmanFilter for the filter, numpy for the readings clock, the torque split, the encoder lead,
the ground-speed latency and the refresh pairs), step by step, on drives drawn by hypothesis; and the
core's refusal of malformed calls."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from reference_observer import TractionObserver
from soilocp._core import ObserverCore
from soilocp.estimation.observer import ObserverConfig
from soilocp.estimation.observer_bank import RESET_REASONS, ROWS, ObserverBank, ObserverInputs, observer_message
from soilocp.model.normal_force import STANDARD_GRAVITY
from soilocp.model.vehicle import DEFAULT_VEHICLE

TOL = 1e-9

drive_params = st.fixed_dictionaries({
    "structure": st.sampled_from(["slip", "shared", "none"]),
    "per_side": st.booleans(),
    "interval_mean": st.booleans(),
    "rate": st.sampled_from([20.0, 100.0, 400.0]),
    # moving, with a ground speed: at a standstill without one the net / resistance split is not
    # determined and any two implementations' summation orders drift apart on it (the numpy kernel did
    # from filterpy's by 1e-9 there too); a standstill is the hostile-sequence test's
    "speed": st.one_of(st.floats(-1.5, -0.3), st.floats(0.3, 2.0)),
    "slip": st.floats(-0.3, 0.6),
    "torque": st.floats(0.0, 60.0),
    "hold_every": st.sampled_from([0, 2, 5, 21]),  # wheel speeds refreshed every n-th sample only
    "torque_every": st.sampled_from([1, 1, 3, 20, 50]),  # torques refreshed every n-th sample only
    "ground_speed": st.sampled_from(["every", "every_10"]),
    "spike_at": st.integers(0, 299),
    "gap_at": st.integers(0, 299),
    "backwards_at": st.integers(0, 299),
    "seed": st.integers(0, 2**31 - 1),
})


def _drive(p: dict, steps: int = 300):
    """(stamp, f_x, yaw rate, pitch, wheel speeds, torques, ground speed or NaN, normal forces) per
    step: a drive at a slip with noise, a wheel-speed spike, a 1 s gap and a stamp going back."""
    rng = np.random.default_rng(p["seed"])
    v, r = DEFAULT_VEHICLE, DEFAULT_VEHICLE.wheel_radius
    t, held, held_torque = 0.0, None, None
    out = []
    for i in range(steps):
        t += 1.0 / p["rate"] + (1.0 if i == p["gap_at"] else 0.0) - (0.05 if i == p["backwards_at"] else 0.0)
        phase = 2 * np.pi * i / steps
        ground = p["speed"] * (1.0 + 0.3 * np.sin(phase))
        omega = ground * (1.0 + p["slip"] * np.cos(phase)) / r + rng.normal(0, 0.03, 4)
        if i == p["spike_at"]:
            omega[1] += 40.0
        if p["hold_every"] and held is not None and i % p["hold_every"]:
            omega = held
        held = omega
        torque = p["torque"] * np.cos(phase + np.arange(4)) + rng.normal(0, 0.5, 4)
        if held_torque is not None and i % p["torque_every"]:
            torque = held_torque
        held_torque = torque
        gs = ground + rng.normal(0, 0.02)
        if p["ground_speed"] == "every_10" and i % 10:
            gs = np.nan
        fz = v.mass * STANDARD_GRAVITY / 4 * (1.0 + 0.2 * np.sin(phase + np.arange(4))) + rng.normal(0, 2.0, 4)
        out.append((t, 0.3 * np.sin(3 * phase) + rng.normal(0, 0.08), 0.1 * np.cos(phase), 0.05 * np.sin(phase),
                    omega.copy(), torque, gs, fz))
    return out


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow], report_multiple_bugs=False)
@given(drive_params)
# found by hypothesis: 20 Hz from t = 1 s, held encoders, the divergence guard resets at step 230 and the
# refresh interval begun there closes at step 232
@example({"structure": "none", "per_side": False, "interval_mean": False, "rate": 20.0, "speed": -1.0, "slip": 0.0,
          "torque": 35.0, "hold_every": 2, "torque_every": 1, "ground_speed": "every", "spike_at": 0, "gap_at": 0,
          "backwards_at": 0, "seed": 0})
def test_core_observer_equals_the_filterpy_reference_step_by_step(p):
    """Every output of every step within 1e-9 (relative and absolute) of the references (filterpy's filter on
    the same model, numpy's readings clock, latency fit and refresh pairs), the same ages, rejected rows,
    resets and refresh flags.  Before each step the reference takes the core's state (x, P,
    gate counters): filterpy sums its products in its own order and inverts S its own way, and over hundreds of
    gated steps on a drawn drive (a held encoder at 20 Hz, a split the data barely determine) the two filters'
    last bits drift apart to 1e-6, as the numpy kernel's did from filterpy's; one step at a time, each step's
    arithmetic is checked without that drift (whole real drives: tests/test_batch.py)."""
    vehicle = DEFAULT_VEHICLE.model_copy(update={
        "drive": "per_side" if p["per_side"] else "per_wheel",
        "wheel_speed_reading": "interval_mean" if p["interval_mean"] else "instant"})
    cfg = ObserverConfig(structure=p["structure"])
    bank = ObserverBank(vehicle, cfg, 1)
    ref = TractionObserver(vehicle, cfg)
    guarded = np.zeros(4, dtype=bool)  # wheels whose open refresh interval began at a divergence-guard reset
    prev_omega = np.full(4, np.nan)
    for k, (t, fx, yaw, pitch, omega, torque, gs, fz) in enumerate(_drive(p)):
        if k:
            ref.kf.x, ref.kf.P, ref._rejections = bank.x[0], bank.P[0], bank.rejections[0]
        o = bank.step(None, ObserverInputs(np.array([t]), np.array([fx]), np.array([yaw]), np.array([pitch]),
                                           omega[None], torque[None], np.array([gs]), fz[None]))
        r = ref.step(t, fx, yaw, pitch, omega, torque, None if np.isnan(gs) else gs, fz)
        if o.reset_reason[0] in ("non_finite_state", "state_out_of_physics"):
            # the product's divergence guard, which filterpy's filter does not have: it must fire exactly
            # where the reference's own state left physics (|omega| or |V| over the limits), and the
            # next step starts both from the core's reset state
            rx = ref.kf.x.ravel()
            speeds = np.abs(rx[bank.layout.omega.start:bank.layout.v + 1])
            limits = np.array([cfg.max_wheel_speed] * 4 + [cfg.max_ground_speed])
            bad = not np.isfinite(rx).all() or not np.isfinite(ref.kf.P).all()
            assert bad or (speeds > limits).any(), (k, o.reset_reason[0], speeds)
            # a refresh interval that starts here (its wheel's reading changed) takes its ground speed from each
            # side's own state, and the reference's left physics: that interval's start is not comparable
            guarded = omega != prev_omega
            prev_omega = omega
            ref._spread.reset()  # the core's restart forgets the slips' spread too (walk.rs)
            continue
        for name in ("mu", "mu_var", "resistance", "gross", "gross_var", "wheel_speed"):
            np.testing.assert_allclose(getattr(o, name)[0], getattr(r, name), rtol=TOL, atol=TOL,
                                       err_msg=f"step {k} {name}")
        np.testing.assert_allclose([o.ground_speed[0], o.yaw_rate[0]], [r.ground_speed, r.yaw_rate], rtol=TOL,
                                   atol=TOL, err_msg=f"step {k}")
        assert (int(o.rejected[0]), bool(o.reset[0])) == (r.rejected, r.reset), k
        # around the filter: the readings clock (exact), the latency fit, the refresh pairs
        np.testing.assert_array_equal(o.normal_force[0], r.normal_force)
        np.testing.assert_array_equal(o.speed_age[0], r.age[:4], err_msg=f"step {k}")
        np.testing.assert_array_equal(o.torque_age[0], r.age[5:], err_msg=f"step {k}")
        assert o.ground_speed_age[0] == r.age[4] or np.isnan(o.ground_speed_age[0]) and np.isnan(r.age[4]), k
        assert o.ground_speed_latency[0] == pytest.approx(r.ground_speed_latency, rel=TOL, abs=TOL), k
        np.testing.assert_array_equal(o.interval_learning[0], r.pairs.active, err_msg=f"step {k}")
        for name in ("interval", "gross", "gross_var", "rim_start", "rim_end", "ground_start", "ground_end",
                     "rim_sigma"):
            field = name if name == "interval" else f"interval_{name}"
            judged = ~guarded if name == "ground_start" else np.ones(4, dtype=bool)
            np.testing.assert_allclose(getattr(o, field)[0][judged], getattr(r.pairs, name)[judged], rtol=TOL,
                                       atol=TOL, err_msg=f"step {k} {field}")
        guarded &= omega == prev_omega  # a new reading closed that interval and started one on the shared state
        prev_omega = omega


def test_reset_reasons_are_worded_from_the_core_codes():
    """A first sample, a stamp going backwards and a time gap restart the filter with their reason; a
    repeated stamp does not."""
    bank = ObserverBank(DEFAULT_VEHICLE, None, 2)

    def step(idx, stamps):
        k = len(stamps)
        return bank.step(np.array(idx), ObserverInputs(
            np.array(stamps, float), np.zeros(k), np.zeros(k), np.zeros(k), np.full((k, 4), 4.0),
            np.zeros((k, 4)), np.full(k, 0.6), np.full((k, 4), 150.0)))

    assert step([0, 1], [1.0, 1.0]).reset_reason == ["start", "start"]
    assert step([1], [1.01]).reset_reason == [""]
    assert step([1, 0], [0.5, 1.0]).reset_reason == ["stamp_backwards", ""]  # vehicle 0: a repeated stamp
    assert step([0], [3.0]).reset_reason == ["time_gap"]
    assert bank.resets_by_reason == {"start": 2, "time_gap": 1, "stamp_backwards": 1, "non_finite_state": 0,
                                     "state_out_of_physics": 0}
    assert list(ObserverCore.reset_reasons) == list(RESET_REASONS)


def test_core_refuses_malformed_calls_naming_the_argument():
    bank = ObserverBank(DEFAULT_VEHICLE, None, 2)
    core = bank._core
    one, quad = np.zeros(1), np.full((1, 4), 100.0)
    ok = dict(stamp=one, specific_force_x=one, yaw_rate=one, pitch=one, wheel_speed=quad, wheel_torque=quad,
              ground_speed=one, normal_force=quad)
    with pytest.raises(ValueError, match=r"idx must be distinct vehicle indices in \[0, 2\)"):
        core.step(np.array([2]), ObserverInputs(**ok))
    with pytest.raises(ValueError, match=r"idx must be distinct"):
        core.step(np.array([0, 0]), ObserverInputs(**{n: np.concatenate([a, a]) for n, a in ok.items()}))
    with pytest.raises(ValueError, match=r"inputs hold 1 samples for 2 vehicle indices"):
        core.step(None, ObserverInputs(**ok))
    bad = dict(ok, wheel_torque=np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"inputs.wheel_torque must be a finite array of shape \(1, 4\)"):
        core.step(np.array([0]), ObserverInputs(**bad))
    bad = dict(ok, pitch=np.zeros(2))
    with pytest.raises(ValueError, match=r"inputs.pitch must be a finite array of shape \(1,\)"):
        core.step(np.array([0]), ObserverInputs(**bad))
    bad = dict(ok, ground_speed=np.array([np.inf]))
    with pytest.raises(ValueError, match=r"inputs.ground_speed must be a finite array"):
        core.step(np.array([0]), ObserverInputs(**bad))
    with pytest.raises(TypeError, match="wheel_speed"):  # not a float array: the bank's check converts it first
        core.step(np.array([0]), ObserverInputs(**dict(ok, wheel_speed=[[1, 2, 3, 4]])))
    # nothing stepped on a refused call
    assert bank.resets_by_reason["start"] == 0
    # the settings, whole, by name: the core checks them as ObserverConfig does, naming the setting
    args = (1, [1.0] * 8, [0.0] * 4)
    kw = dict(per_side=False, interval_mean=False, bridge_slip=0.005)
    with pytest.raises(ValueError, match='observer settings: structure = "paper" must be one of slip, shared, '
                                         'per_wheel, none'):
        ObserverCore(*args, {"structure": "paper"}, **kw)
    with pytest.raises(ValueError, match="observer settings: gate_patience = 1.5 must be a whole number"):
        ObserverCore(*args, {"gate_patience": 1.5}, **kw)
    with pytest.raises(ValueError, match="observer settings: full_rate_share = 1 must be < 1"):
        ObserverCore(*args, {"full_rate_share": 1.0}, **kw)
    with pytest.raises(ValueError, match='unknown setting "q_muu"'):
        ObserverCore(*args, {"q_muu": 1.0}, **kw)
    with pytest.raises(ValueError, match="discretization \"expm\": the observer kernel implements 'series' only"):
        ObserverCore(*args, {"discretization": "expm"}, **kw)
    ObserverCore(*args, {}, **kw)  # every setting at its default


def test_the_bank_names_a_malformed_input_field():
    """ObserverBank.step: ValueError naming the field, from the core or (lists, other dtypes) the Python check."""
    bank = ObserverBank(DEFAULT_VEHICLE, None, 1)

    def inputs(**change):
        base = dict(stamp=np.array([1.0]), specific_force_x=np.zeros(1), yaw_rate=np.zeros(1), pitch=np.zeros(1),
                    wheel_speed=np.full((1, 4), 4.0), wheel_torque=np.zeros((1, 4)), ground_speed=np.full(1, 0.6),
                    normal_force=np.full((1, 4), 150.0))
        return ObserverInputs(**{**base, **change})

    with pytest.raises(ValueError, match=r"inputs.wheel_speed must be a finite array"):
        bank.step(None, inputs(wheel_speed=np.array([[4.0, np.nan, 4.0, 4.0]])))
    with pytest.raises(ValueError, match=r"inputs.normal_force must be a finite array of shape \(1, 4\)"):
        bank.step(None, inputs(normal_force=[[150.0] * 3]))
    with pytest.raises(ValueError, match=r"inputs.specific_force_x must be a finite array of shape \(2,\)"):
        bank.step(None, inputs(stamp=np.array([1.0, 2.0])))
    two = ObserverInputs(*(np.concatenate([a, a]) for a in vars(inputs()).values()))
    with pytest.raises(ValueError, match=r"inputs hold 2 samples for 1 vehicle indices"):
        bank.step(None, two)
    assert np.isnan(bank.last_stamp).all()
    # lists and integer arrays are converted
    o = bank.step(None, inputs(wheel_torque=[[1, 2, 3, 4]], pitch=[0.0]))
    assert o.reset_reason == ["start"] and o.mu.shape == (1, 4) and o.rejected.dtype == np.int64


def test_the_message_holds_every_row_of_its_vehicle():
    """observer_message: every row the core names is the message field of that name, for the vehicle asked,
    with the rejections and the reset's reason; the rows read by name are views of the core's blocks."""
    bank = ObserverBank(DEFAULT_VEHICLE, None, 3)
    rng = np.random.default_rng(5)
    stamps = np.ones(3)
    for n in range(40):
        ix = np.sort(rng.choice(3, int(rng.integers(1, 4)), replace=False))
        stamps[ix] += 0.01 if n != 30 else -0.5  # a stamp going back: a reset with its reason
        k = ix.size
        out = bank.step(ix, ObserverInputs(
            stamps[ix].copy(), rng.normal(0, 0.5, k), rng.normal(0, 0.1, k), np.zeros(k),
            rng.uniform(3.0, 5.0, (k, 4)), rng.uniform(0.0, 8.0, (k, 4)), rng.uniform(0.5, 0.8, k),
            np.full((k, 4), 150.0)))
        assert np.shares_memory(out.mu, out.quads) and out.ground_speed_measured.dtype == bool
        for j in range(k):
            msg = observer_message(f"v{ix[j]}", n, float(stamps[ix[j]]), out, j, 1.1, 0.02)
            for name in ROWS:
                want = getattr(out, name)[j].tolist()
                assert getattr(msg, name) == (tuple(want) if isinstance(want, list) else want), (n, j, name)
            assert (msg.rejected_measurements, msg.reset_reason) == (int(out.rejected[j]), out.reset_reason[j])
            assert (msg.vehicle_id, msg.seq, msg.torque_scale, msg.torque_scale_std) == (f"v{ix[j]}", n, 1.1, 0.02)
    assert bank.resets_by_reason["stamp_backwards"] >= 1


def test_rows_that_miss_the_message_fail_at_import(monkeypatch):
    """A row the core adds without its ObserverOutput field (or the reverse) refuses the import."""
    from soilocp.estimation import observer_bank

    _check_rows = observer_bank._check_rows
    _check_rows()
    with monkeypatch.context() as m:
        m.setattr(observer_bank, "ROWS", {**ROWS, "slip_angle": (1, len(observer_bank.FLAT_FIELDS))})
        with pytest.raises(ImportError, match="slip_angle"):
            _check_rows()
    with monkeypatch.context() as m:
        m.setattr(observer_bank, "ROWS", {f: at for f, at in ROWS.items() if f != "gross"})
        with pytest.raises(ImportError, match="gross"):
            _check_rows()
    with monkeypatch.context() as m:  # a row of another kind than its field: a flat row for a Quad
        m.setattr(observer_bank, "ROWS", {**ROWS, "mu": (1, 0)})
        with pytest.raises(ImportError, match="mu"):
            _check_rows()


def test_the_observer_bridges_zero_slip_with_the_model_constants():
    """One zero-slip bridge: the observer's motion resistance (eq. 4's constant part) takes the model's
    ``constants.bridge_slip``, the same that bridges the traction curve, so a config that sets it reaches both."""
    from soilocp.estimation.estimate import estimate_lines
    from soilocp.estimation.pipeline import PipelineConfig
    from soilocp.model.constants import ModelConstants
    from soilocp.sim.scenarios import get_scenario
    from soilocp.sim.simulator import simulate

    lines = [s.model_dump_json() for s, _ in simulate(get_scenario("sand"), duration=4.0, seed=0)]
    mu = {}
    for bridge in (0.0, 0.02):
        cfg = PipelineConfig(constants=ModelConstants(bridge_slip=bridge))
        mu[bridge] = np.array([r["mu"] for r in estimate_lines(lines, cfg)], dtype=float)
    assert mu[0.0].shape == mu[0.02].shape and np.isfinite(mu[0.0]).any()
    assert np.nanmax(np.abs(mu[0.0] - mu[0.02])) > 1e-6
    with pytest.raises(Exception, match="bridge_slip"):
        PipelineConfig.model_validate({"observer": {"bridge_slip": 0.01}})


@pytest.mark.parametrize("structure", ["slip", "shared", "per_wheel", "none"])
def test_the_state_layout_is_the_cores(structure):
    """StateLayout reads the core's layout: its blocks tile the state the core's filter holds, in order."""
    from soilocp.estimation.observer import StateLayout

    layout = StateLayout.of(structure)
    bank = ObserverBank(DEFAULT_VEHICLE, ObserverConfig(structure=structure), 1)
    assert bank.x.shape == (1, layout.n) and bank.P.shape == (1, layout.n, layout.n)
    blocks = [layout.mu, layout.res, layout.lat, layout.omega, slice(layout.v, layout.v + 1),
              slice(layout.psi, layout.psi + 1), slice(layout.bias, layout.bias + 1)]
    assert [b.start for b in blocks[1:]] == [b.stop for b in blocks[:-1]] and blocks[-1].stop == layout.n
    assert (layout.n_res, layout.n_lat) == {"slip": (2, 1), "shared": (1, 1), "per_wheel": (4, 4), "none": (0, 1)}[structure]
    with pytest.raises(ValueError, match="slip, shared, per_wheel or none"):
        StateLayout.of("paper")
