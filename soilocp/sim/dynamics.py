"""One simulated drive, stepped: the rover's state, its backward-Euler sub-steps (Newton on
omega_1..4, V, psi'), the terrain under each wheel, and the sensor sample and truth record at
each sample instant.  The model and the numerics are described in :mod:`soilocp.sim.simulator`,
which builds a :class:`RoverDrive` for every ``simulate`` call."""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Iterator

import numpy as np

from soilocp.schemas.sensor import SensorSample

from soilocp.model.constants import ModelConstants
from soilocp.model.normal_force import STANDARD_GRAVITY, gravity_from_attitude, normal_forces
from soilocp.model.ocp import ocp_from_soil_strength
from soilocp.sim.scenarios import Scenario
from soilocp.sim.controller import SweepController
from soilocp.sim.field import true_position
from soilocp.sim.sensor_models import SensorSuite, per_side_readings
from soilocp.sim.truth import TruthRecord
from soilocp.model.traction import gross_traction_with_derivatives, net_traction_with_derivatives

#: m/s: the drawbar draft ramps in as tanh(V / _LOAD_EPS), so that it resists motion like friction
_LOAD_EPS = 0.05



class _TractionTable:
    """Gross (eq. 3) and net (eq. 6) traction and their slip derivatives, sampled from
    :mod:`soilocp.model.traction` on a uniform slip grid per soil strength and linearly interpolated.

    The integrator's inner loop is scalar Python (four wheels: numpy's per-call overhead would
    dominate), so the tables are Python lists on a uniform grid, indexed in O(1) by
    ``RoverDrive._substep``: j = int((S + SPAN) / STEP), then linear interpolation.
    """

    STEP = 1e-4
    SPAN = 2.0  # |S| <= 2 for eq. 1 with the max() denominator

    def __init__(self, constants: ModelConstants):
        self.constants = constants
        self.n = int(round(2 * self.SPAN / self.STEP)) + 1
        self.grid = np.linspace(-self.SPAN, self.SPAN, self.n)
        self._tabs: dict[float, tuple[list[float], ...]] = {}

    def tables(self, k: float) -> tuple[list[float], list[float], list[float], list[float]]:
        """(g, dg/dS, mu, dmu/dS) sampled on the grid for soil strength k (built once per k)."""
        k = float(k)
        if k not in self._tabs:
            g, dg, _ = gross_traction_with_derivatives(self.grid, k, self.constants)
            mu, dmu, _ = net_traction_with_derivatives(self.grid, k, self.constants)
            self._tabs[k] = (g.tolist(), dg.tolist(), mu.tolist(), dmu.tolist())
        return self._tabs[k]


class RoverDrive:
    """State and stepping of one simulated drive (scalar Python inner loop over the 4 wheels)."""

    def __init__(self, sc: Scenario, *, duration, rate, rng, vehicle, constants, mode, noise, vehicle_id, ctl, par,
                 torque_command=None, drawbar_load=None, start=None, drive_command=None):
        self.sc, self.duration, self.rate, self.mode = sc, duration, rate, mode
        self.v, self.c, self.ctl, self.par, self.vehicle_id = vehicle, constants, ctl, par, vehicle_id
        self.interval = 1.0 / rate
        self.n_sub = max(1, math.ceil(self.interval / par.max_substep - 1e-9))
        self.h = self.interval / self.n_sub
        self.sensors = SensorSuite(noise, rng, self.interval)
        self.table = _TractionTable(constants)
        self.x_w = np.array(vehicle.wheel_x)
        self.y_w = np.array(vehicle.wheel_y)
        self.ys = [float(q) for q in vehicle.wheel_y]
        self.xs = [float(q) for q in vehicle.wheel_x]
        self._starts = [float(q) for q in sc.starts]
        self.front = [xq > 0 for xq in vehicle.wheel_x]
        self.absx = [abs(float(q)) for q in vehicle.wheel_x]
        # normal_forces is linear in the specific force (B of eq. 24 is): Fz = f @ N exactly.
        self.fz_matrix = normal_forces(vehicle, np.eye(3))
        self._nz = self.fz_matrix.T.tolist()  # per wheel: (dFz/dfx, dFz/dfy, dFz/dfz)
        self._ocp_cache: dict[float, object] = {}
        # state
        self.t = 0.0
        self.w = [0.0] * 4  # wheel speeds, rad/s
        self.V = 0.0  # CoM longitudinal speed, m/s
        self.r = 0.0  # yaw rate, rad/s
        self.prev = [0.0] * 6  # previous (w, V, r), for the Newton predictor
        self.dist = 0.0
        self.heading = 0.0
        self.z = 0.0
        self.wheel_angle = [0.0] * 4
        self.acc = 0.0  # V' of the last sub-step
        self.i_wheel = [0.0] * 4
        self.torque = [0.0] * 4
        self.slips, self.gross, self.mus = [0.0] * 4, [0.0] * 4, [0.0] * 4
        self.controller = SweepController(sc, vehicle, ctl, mode, self.h)
        self.energy = dict(motor_work=0.0, slip_dissipation=0.0, resistance_work=0.0, yaw_dissipation=0.0)
        self.newton_iters = 0
        self.newton_failures = 0
        self.substeps = 0
        self.torque_command, self.drawbar_load = torque_command, drawbar_load
        self.drive_command = drive_command
        self.held_torque: list[float] | None = None  # external torque command over this interval
        self.load = 0.0  # drawbar draft force over this interval, N
        self.drawbar_work = 0.0  # work done against the draft, J (not in the truth record's balance)
        # true planar position of the CoM (soilocp.sim.field.StartPose; docs/map.md)
        self.start = start
        self.px, self.py = (start.x, start.y) if start is not None else (0.0, 0.0)
        self.heading0 = start.heading if start is not None else 0.0
        self._terrain()
        self.f_used = self._specific_force()
        self.fz = self._fz(self.f_used)

    # --- terrain -------------------------------------------------------------------------
    def _terrain(self) -> None:
        segs = self.sc.segments
        if len(segs) == 1 and hasattr(self, "seg"):
            return
        # the segments are laid out along the path: backwards in reverse, where the rear wheels lead
        sgn = self.ctl.direction
        starts, d = self._starts, sgn * self.dist
        seg_wheels = [max(bisect.bisect_right(starts, d + sgn * xi) - 1, 0) for xi in self.xs]
        seg_com = max(bisect.bisect_right(starts, d) - 1, 0)
        if hasattr(self, "seg") and seg_com == self.seg and seg_wheels == self.seg_wheels:
            return
        self.seg_wheels, self.seg = seg_wheels, seg_com
        seg = segs[self.seg]
        self.k_wheels = np.array([segs[j].soil_strength for j in seg_wheels])
        self.k_tabs = [self.table.tables(k) for k in self.k_wheels]
        self.roll, self.pitch = seg.cross_slope, 0.0 - seg.grade  # (0.0 - x: no "-0.0" in the logs)
        self.f_grav = [float(q) for q in gravity_from_attitude(self.roll, self.pitch, STANDARD_GRAVITY)]

    def _specific_force(self) -> tuple[float, float, float]:
        """True specific force: acceleration (V', V psi', 0) + gravity reaction (eq. 20), body frame."""
        fg = self.f_grav
        return (fg[0] + self.acc, fg[1] + self.V * self.r, fg[2])

    def _fz(self, f) -> list[float]:
        """Zero-warp normal forces (eqs. 16-25 corrected), via the exact linear map of normal_forces."""
        return [n[0] * f[0] + n[1] * f[1] + n[2] * f[2] for n in self._nz]

    # --- one backward-Euler sub-step -----------------------------------------------------
    def _substep(self, final: bool) -> None:
        """Backward Euler for (omega_1..4, V, psi') by Newton's method (analytic Jacobian, the
        diagonal wheel block eliminated).  Eq. 13 per wheel with gross traction, the longitudinal
        and yaw equations (eqs. 11-12) with net traction, and the normal forces (zero-warp solution
        of eqs. 16-25) from the specific force of the SAME step, f = ((V - V0)/h, V psi', 0) + g_R.

        The load transfer is implicit on purpose: with h/L = 0.6 and |mu| ~ 1 the loop
        acceleration -> Fz -> traction -> acceleration has a gain above 1 (one axle driving, the
        other braking), and a one-step lag turns it into a numerical oscillation of the whole
        rover.

        The last sub-step before a sample (``final``) iterates until the update is below
        ``newton_tol`` and keeps the iterate whose forces were evaluated, so that the reported state
        and forces are exactly consistent; intermediate sub-steps accept the first update once it is
        below ``newton_loose_tol`` (then they are linearly implicit Euler steps, also L-stable)."""
        v, ctl, par, h = self.v, self.ctl, self.par, self.h
        t_new = self.t + h
        self._terrain()
        w_ref = self.controller.references(t_new, self.V, self.r)
        R, m, Iw, Iz, ys, ax = v.wheel_radius, v.mass, v.wheel_inertia, v.yaw_inertia, self.ys, self.absx
        kp, tmax = ctl.wheel_kp, ctl.torque_limit
        held, load = self.held_torque, self.load
        if held is not None:
            kp = 0.0  # torque held over the interval: no d T / d omega in the Jacobian
        t_int = [ctl.wheel_ki * q for q in self.i_wheel]
        muy, eps, floor, tol = par.lateral_resistance, par.yaw_rate_eps, par.slip_floor, par.newton_tol
        loose = par.newton_loose_tol
        gx, gy, gz = self.f_grav  # m V' = sum(mu Fz) - m gx  (gx = g sin(grade))
        nz = self._nz
        w0, V0, r0 = self.w, self.V, self.r
        x0 = [*w0, V0, r0]
        x = [2.0 * a - b for a, b in zip(x0, self.prev)]  # linear predictor
        tabs = self.k_tabs
        span, inv_step, last = self.table.SPAN, 1.0 / self.table.STEP, self.table.n - 1
        Fw, BV, Br, inv, gs, mus, tq, traw, ss, fz, cv = ([0.0] * 4 for _ in range(11))
        # the truth in the frame of travel (eq. 1 and the traction law as for forward travel, mirrored)
        s_tr, g_tr, mu_tr = ([0.0] * 4 for _ in range(3))
        # a wheel's direction of travel is the one its drive commands: backwards in a reverse drive, and
        # on the spot, each side its own way.  (Not the sign of V_i: a robot that rolls back on a climb
        # before its wheels grip still "drives forward", and eq. 1 then reads |S| > 1, as it should.)
        back = [ctl.reverse or (ctl.turn_in_place and q < 0.0) for q in w_ref]
        # skid steer: the two wheels of a side are chained to one motor (one speed per side)
        units = ((0, 1), (2, 3)) if v.drive == "per_side" else ((0,), (1,), (2,), (3,))
        hkp, hR, inv_h = h * kp, h * R, 1.0 / h
        for it in range(par.newton_max_iter):
            V, r = x[4], x[5]
            f = (gx + (V - V0) * inv_h, gy + V * r, gz)
            lz = lzV = lzr = 0.0
            sum_fx = sum_yfx = 0.0
            eVV = eVr = eRV = eRr = 0.0  # sums for the V and yaw rows' own partials
            a11c = a12c = a21c = a22c = b1c = b2c = 0.0
            for i in range(4):
                wi, yi = x[i], ys[i]
                nx_, ny_, nz_ = nz[i]
                fzi = nx_ * f[0] + ny_ * f[1] + nz_ * f[2]
                zV = nx_ * inv_h + ny_ * r  # dFz/dV
                zr = ny_ * V  # dFz/d psi'
                lz += ax[i] * fzi
                lzV += ax[i] * zV
                lzr += ax[i] * zr
                vi = V - r * yi
                # eq. 1 exactly as soilocp.model.slip.slip_ratio (floored denominator; the truth test
                # checks the reported slip against slip_ratio) and its partials for the Jacobian
                rho = wi * R
                arho, av = abs(rho), abs(vi)
                d = max(arho, av, floor)
                s = (rho - vi) / d
                if arho >= av and arho >= floor:
                    sw = (vi if rho > 0 else -vi) / (d * d) * R
                    sv = -1.0 / d
                elif av >= floor:
                    sw = R / d
                    sv = (-rho if vi > 0 else rho) / (d * d)
                else:
                    sw = R / d
                    sv = -1.0 / d
                # _TractionTable lookup, inline (this loop is the hot path)
                u = (s + span) * inv_step
                if u <= 0.0:
                    j, fr = 0, 0.0
                elif u >= last:
                    j, fr = last - 1, 1.0
                else:
                    j = int(u)
                    fr = u - j
                tg, tdg, tmu, tdmu = tabs[i]
                g = tg[j] + fr * (tg[j + 1] - tg[j])
                dg = tdg[j] + fr * (tdg[j + 1] - tdg[j])
                mu = tmu[j] + fr * (tmu[j + 1] - tmu[j])
                dmu = tdmu[j] + fr * (tdmu[j + 1] - tdmu[j])
                # travel backwards (V_i < 0): the same drive mirrored (x -> -x).  Eq. 1 for the direction
                # of travel gives the driving slip S_d = -s; net traction is odd (eq. 6), so the body force
                # -mu(S_d) Fz = mu(s) Fz is unchanged, but the motion resistance (eq. 4, even in S) now
                # opposes backward travel: the wheel's eq. 13 sees -g(S_d) = mu(s) - r(|s|) = 2 mu - g.
                if back[i]:
                    g, dg = 2.0 * mu - g, 2.0 * dmu - dg
                    s_tr[i], g_tr[i], mu_tr[i] = -s, -g, -mu
                else:
                    s_tr[i], g_tr[i], mu_tr[i] = s, g, mu
                tr = kp * (w_ref[i] - wi) + t_int[i] if held is None else held[i]
                if tr > tmax:
                    T, kpe = tmax, 0.0
                elif tr < -tmax:
                    T, kpe = -tmax, 0.0
                else:
                    T, kpe = tr, hkp
                # wheel row (eq. 13) and its partials
                fwi = Iw * (wi - w0[i]) - h * T + hR * g * fzi
                k1 = hR * fzi * dg
                invi = 1.0 / (Iw + kpe + k1 * sw)
                bvi = k1 * sv + hR * g * zV
                bri = -k1 * sv * yi + hR * g * zr
                # body rows: d(mu Fz)/dV and d(mu Fz)/d psi'
                ai = fzi * dmu
                dFV = ai * sv + mu * zV
                dFr = -ai * sv * yi + mu * zr
                eVV += dFV
                eVr += dFr
                eRV += yi * dFV
                eRr += yi * dFr
                cv[i] = -h * ai * sw  # CV_i: the body row's d/d omega_i (and Cr_i = -CV_i y_i)
                fx = mu * fzi
                sum_fx += fx
                sum_yfx += yi * fx
                Fw[i], BV[i], Br[i], inv[i] = fwi, bvi, bri, invi
                gs[i], mus[i], tq[i], traw[i], ss[i], fz[i] = g, mu, T, tr, s, fzi
            # eliminate the wheel rows: each wheel (or, skid steer, each side's chained pair: one speed,
            # the pair's rows summed) couples to the body rows through CV / D
            for u in units:
                d_u = sum(1.0 / inv[i] for i in u)
                f_u, bv_u, br_u = sum(Fw[i] for i in u), sum(BV[i] for i in u), sum(Br[i] for i in u)
                q = sum(cv[i] for i in u) / d_u
                yu = ys[u[0]]
                a11c += q * bv_u
                a12c += q * br_u
                a21c -= q * yu * bv_u
                a22c -= q * yu * br_u
                b1c += q * f_u
                b2c -= q * yu * f_u
                for i in u:
                    Fw[i], BV[i], Br[i], inv[i] = f_u, bv_u, br_u, 1.0 / d_u
            th = math.tanh(r / eps)
            FV = m * (V - V0) - h * (sum_fx - m * gx)
            if load:  # draft opposing the motion, implicit like the rest of the body row
                thl = math.tanh(V / _LOAD_EPS)
                FV += h * load * thl
            Fr = Iz * (r - r0) + h * (sum_yfx + muy * lz * th)
            A11 = m - h * eVV - a11c
            if load:
                A11 += h * load * (1.0 - thl * thl) / _LOAD_EPS
            A12 = -h * eVr - a12c
            A21 = h * (eRV + muy * lzV * th) - a21c
            A22 = Iz + h * (eRr + muy * (lzr * th + lz * (1.0 - th * th) / eps)) - a22c
            b1 = FV - b1c
            b2 = Fr - b2c
            det = A11 * A22 - A12 * A21
            dV = (b1 * A22 - A12 * b2) / det
            dr = (A11 * b2 - A21 * b1) / det
            dw = [(Fw[i] - BV[i] * dV - Br[i] * dr) * inv[i] for i in range(4)]
            big = max(abs(dV), abs(dr), abs(dw[0]), abs(dw[1]), abs(dw[2]), abs(dw[3]))
            if big < tol:
                break  # accept x itself: the stored forces are exactly those of the accepted state
            x = [x[0] - dw[0], x[1] - dw[1], x[2] - dw[2], x[3] - dw[3], V - dV, r - dr]
            if not final and big < loose:
                break  # intermediate sub-step: one small Newton update (linearly implicit Euler) suffices
        else:
            self.newton_failures += 1
        self.newton_iters += it + 1
        self.substeps += 1
        w, V, r = x[:4], x[4], x[5]
        # wheel PI integrators, with anti-windup (hold while saturated and pushing further)
        for i in range(4):
            err = w_ref[i] - w[i]
            if abs(traw[i]) < tmax or (err > 0) != (traw[i] > 0):
                self.i_wheel[i] += h * err
        # energy book (backward Euler: powers at the new state, torques held over the step)
        e = self.energy
        vis = [V - r * yi for yi in ys]
        pm = ps = pr = 0.0
        for i in range(4):
            pm += tq[i] * w[i]
            ps += fz[i] * gs[i] * (R * w[i] - vis[i])
            pr += fz[i] * (gs[i] - mus[i]) * vis[i]
        e["motor_work"] += h * pm
        e["slip_dissipation"] += h * ps
        e["resistance_work"] += h * pr
        e["yaw_dissipation"] += h * muy * lz * th * r
        if load:
            self.drawbar_work += h * load * math.tanh(V / _LOAD_EPS) * V
        self.z += h * V * gx / STANDARD_GRAVITY
        # advance
        self.prev = x0
        self.acc = (V - V0) / h
        self.w, self.V, self.r = w, V, r
        self.torque = tq[:]
        self.slips, self.gross, self.mus = s_tr, g_tr, mu_tr
        self.f_used, self.fz = f, fz[:]
        # trapezoid rule: the encoder's count difference is then the interval's mean speed to O(h^2),
        # as on the real wheel (the right-Riemann sum h * w_new read it (1 - 1/n_sub) of the true lag)
        self.wheel_angle = [a + 0.5 * h * (wi + wo) for a, wi, wo in zip(self.wheel_angle, w, w0)]
        self.dist += h * V
        hm = self.heading0 + self.heading + 0.5 * h * r  # midpoint heading of the sub-step
        self.px += h * V * math.cos(hm)
        self.py += h * V * math.sin(hm)
        self.heading += h * r
        self.t = t_new

    # --- records -------------------------------------------------------------------------
    def _ocp(self, k: float):
        if k not in self._ocp_cache:
            self._ocp_cache[k] = ocp_from_soil_strength(k, self.c)
        return self._ocp_cache[k]

    def _records(self, seq: int) -> tuple[SensorSample, TruthRecord]:
        v = self.v
        stamp = seq / self.rate
        w = np.array(self.w)
        # the accepted Newton iterate's own slip and forces: exactly what the dynamics used
        # (eq. 1 as slip_ratio; eqs. 3/6 from the sampled table, within 2e-7 of soilocp.model.traction)
        s, g, mu = np.array(self.slips), np.array(self.gross), np.array(self.mus)
        seg = self.sc.segments[self.seg]
        ocp = self._ocp(seg.soil_strength)
        ke = 0.5 * (v.mass * self.V**2 + v.yaw_inertia * self.r**2 + v.wheel_inertia * float(w @ w))
        tup = lambda a: tuple(float(q) for q in a)  # noqa: E731
        # the true motion: the truth record states it, the sensors read it
        motion = dict(specific_force=self.f_used, roll=self.roll, pitch=self.pitch, yaw_rate=self.r,
                      wheel_speed=self.w, wheel_torque=self.torque, ground_speed=self.V)
        truth = TruthRecord(
            **{name: tup(a) if np.ndim(a) else a for name, a in motion.items()},
            vehicle_id=self.vehicle_id,
            seq=seq,
            stamp=stamp,
            mode=self.mode,
            segment=self.seg,
            soil_class=seg.soil_class,
            soil_strength=seg.soil_strength,
            wheel_soil_strength=tup(self.k_wheels),
            grade=seg.grade,
            cross_slope=seg.cross_slope,
            distance=self.dist,
            heading=self.heading,
            x=self.px,
            y=self.py,
            slip=tup(s),
            mu=tup(mu),
            motion_resistance=tup(g - mu),
            gross_traction=tup(g),
            normal_force=tup(self.fz),
            speed_command=self.controller.speed_cmd,
            slip_command=self.controller.slip_cmd,
            mu_T=ocp.mu_T,
            S_T=ocp.S_T,
            S_E=ocp.S_E,
            kinetic_energy=ke,
            potential_energy=v.mass * STANDARD_GRAVITY * self.z,
            **self.energy,
        )
        read = self.sensors.read(wheel_angle=self.wheel_angle, **motion)
        if v.drive == "per_side":
            read = per_side_readings(read)
        if self.start is not None:  # true positions in the samples (a perfect odometry / GNSS)
            read.update(true_position(self.start, self.px, self.py, self.heading0 + self.heading))
        sample = SensorSample(vehicle_id=self.vehicle_id, seq=seq, stamp=stamp, **read)
        return sample, truth

    def samples(self) -> Iterator[tuple[SensorSample, TruthRecord]]:
        n = itertools.count() if math.isinf(self.duration) else range(max(1, int(round(self.duration * self.rate))))
        for seq in n:
            if seq:
                for k in range(self.n_sub):
                    self._substep(final=k == self.n_sub - 1)
                if not (all(map(math.isfinite, (*self.w, self.V, self.r))) and max(map(abs, self.f_used)) < 100.0):
                    raise RuntimeError(
                        f"simulation diverged at t={self.t:.4f} s: wheel speeds {self.w}, V {self.V}, yaw rate "
                        f"{self.r}, specific force {self.f_used} (controller gains or vehicle out of range?)"
                    )
            records = self._records(seq)
            yield records
            if self.torque_command is not None:
                cmd = [float(q) for q in self.torque_command(records[0])]
                if len(cmd) != 4 or not all(map(math.isfinite, cmd)):
                    raise ValueError(f"wheel_torque_command must return 4 finite torques (N m), got {cmd!r}")
                tmax = self.ctl.torque_limit
                self.held_torque = [min(max(q, -tmax), tmax) for q in cmd]
            if self.drive_command is not None:
                speed, slip = self.drive_command(records[0])
                speed = float(speed)
                if not math.isfinite(speed) or (slip is not None and not (math.isfinite(slip) and 0.0 <= slip < 0.95)):
                    raise ValueError(f"drive_command must return a finite speed (m/s) and a slip in [0, 0.95) or None, "
                                     f"got {speed!r}, {slip!r}")
                self.controller.command = (speed, None if slip is None else float(slip))
            if self.drawbar_load is not None:
                f = float(self.drawbar_load(self.t, self.V))
                if not (math.isfinite(f) and f >= 0):
                    raise ValueError(f"drawbar_load must return a finite draft force >= 0 N, got {f!r}")
                self.load = f
