//! The observer state's index map for each structure (soilocp.estimation.observer.StateLayout):
//! [mu_1..4, resistance (n_res), lateral (n_lat), omega_1..4, V, psi_dot, bias].

/// Number of measurement rows: f_x, yaw rate, omega_1..4, ground speed.
pub const N_MEAS: usize = 7;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// longitudinal resistance states: 2 (slip), 1 (shared), 4 (per wheel) or 0 (none)
    pub n_res: usize,
    /// lateral resistance states: 1 or 4
    pub n_lat: usize,
}

impl Layout {
    /// The layout of a structure name; `Err` naming it otherwise.
    pub fn of(structure: &str) -> Result<Layout, String> {
        match structure {
            "slip" => Ok(Layout { n_res: 2, n_lat: 1 }),
            "shared" => Ok(Layout { n_res: 1, n_lat: 1 }),
            "per_wheel" => Ok(Layout { n_res: 4, n_lat: 4 }),
            "none" => Ok(Layout { n_res: 0, n_lat: 1 }),
            other => Err(format!(
                "observer structure must be slip, shared, per_wheel or none, got {other:?}"
            )),
        }
    }

    pub const MU: usize = 0;

    pub fn res(&self) -> usize {
        4
    }

    pub fn lat(&self) -> usize {
        4 + self.n_res
    }

    pub fn omega(&self) -> usize {
        4 + self.n_res + self.n_lat
    }

    pub fn v(&self) -> usize {
        self.omega() + 4
    }

    pub fn psi(&self) -> usize {
        self.v() + 1
    }

    pub fn bias(&self) -> usize {
        self.psi() + 1
    }

    pub fn n(&self) -> usize {
        self.bias() + 1
    }

    /// One value per state by kind (`res_slope` for the second resistance state of `slip`).
    #[allow(clippy::too_many_arguments)]
    pub fn per_state(
        &self,
        mu: f64,
        res: f64,
        res_slope: f64,
        lat: f64,
        omega: f64,
        v: f64,
        psi: f64,
        bias: f64,
    ) -> Vec<f64> {
        let mut out = vec![0.0; self.n()];
        out[..4].fill(mu);
        out[self.res()..self.lat()].fill(res);
        if self.n_res == 2 {
            out[self.res() + 1] = res_slope;
        }
        out[self.lat()..self.omega()].fill(lat);
        out[self.omega()..self.v()].fill(omega);
        out[self.v()] = v;
        out[self.psi()] = psi;
        out[self.bias()] = bias;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_match_the_python_layout() {
        // StateLayout.of(s).n in soilocp.estimation.observer
        for (s, n, v) in [
            ("slip", 14, 11),
            ("shared", 13, 10),
            ("per_wheel", 19, 16),
            ("none", 12, 9),
        ] {
            let l = Layout::of(s).unwrap();
            assert_eq!((l.n(), l.v()), (n, v), "{s}");
        }
        assert!(Layout::of("paper").is_err());
    }
}
