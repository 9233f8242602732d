//! GS4 time integration: parameters, amplification matrices, explicit stability limits and
//! scalar reference steppers.
//!
//! Everything here follows `ALGORITHM.md` §1 ("GS4 time integration"):
//!
//! * §1.1 — the parameters $W_1\Lambda_k$, $\lambda_k$, $W_1$ as functions of the spectral radii
//!   $(\rho_\infty, \rho^s_\infty)$, with the **corrected** $\lambda_3 = \lambda_5/2$ (erratum E1: the
//!   paper prints $\lambda_3 = 1/\lambda_5$, which makes the implicit GS4-II amplification matrix
//!   unstable at high frequency). See [`Gs4Params`].
//! * §1.2 — the two step formats: GS4-1 for first-order fields $\dot y = g(y, t)$, eq. (1.2) and its
//!   linearly-implicit variant (1.3) ([`step_first_order`]), and GS4-II for second-order systems
//!   $\ddot x = f(x, \dot x, t)$, eq. (1.4) ([`step_second_order_explicit`],
//!   [`step_second_order_linear_implicit`]).
//! * §1.3 — properties: amplification matrices ([`Gs4Params::amplification_first_order`],
//!   [`Gs4Params::amplification_second_order`]), spectral radii ([`spectral_radius_2x2`],
//!   [`spectral_radius_3x3`]) and the explicit stability limits ([`Gs4Params::z_crit`],
//!   [`Gs4Params::omega_crit`]).
//! * §1.4 — the unit-test catalogue T1–T6 lives in `tests/it/gs4.rs`.
//!
//! The ground truth for every number is `design/checks/gs4_check.py` (and `gs4_ref.py`,
//! `gs4_table.py`, `astab.py`, `gs4_sym.py`); the amplification matrices below are built exactly as
//! there.
//!
//! # Notation
//!
//! $\Delta t$ \[s\] is the time step. For the first-order test equation $\dot y = -k y$ ($k$ \[s⁻¹\])
//! the dimensionless step is $z = k\Delta t$; for the second-order test equation
//! $\ddot x + 2\zeta\omega\dot x + \omega^2 x = 0$ ($\omega$ \[rad s⁻¹\], damping ratio $\zeta$ \[–\])
//! it is $\Omega = \omega\Delta t$.
//!
//! # Stability limits
//!
//! [`Gs4Params::z_crit`] and [`Gs4Params::omega_crit`] are evaluated in **closed form** from the
//! Schur–Cohn (Jury) conditions on the characteristic polynomial of the explicit amplification
//! matrix, so they are exact, allocation-free and take nanoseconds. The binding condition is the
//! root crossing $\lambda = -1$ (flutter at the Nyquist frequency):
//!
//! * GS4-1 (exact, all four Jury conditions are affine in $z$):
//!   $z_{crit} = \dfrac{4W_1\Lambda_6 - 2}{2\lambda_5 + 2W_1\Lambda_4 - \lambda_4}$,
//!   e.g. $(0.5, 0)$: $8/7 = 1.143$; $(1, 1)$: $0$.
//! * GS4-II: $p(-1) = 0$ gives
//!   $\alpha\,\Omega^2 + 2\zeta\beta\,\Omega = 8W_1\Lambda_6 - 4$ with
//!   $\beta = 4\lambda_5 + 4W_1\Lambda_4 - 2\lambda_4$ and
//!   $\alpha = \lambda_1\lambda_4 - 2\lambda_1\lambda_5 - 2\lambda_2 + 4\lambda_3 -
//!   2\lambda_4W_1\Lambda_1 + 4\lambda_5W_1\Lambda_1 + 4W_2\Lambda_2$
//!   ($= 4W_1\Lambda_4\lambda_5$ for the §1.1 family), so
//!   undamped $\Omega_{crit}^2 = (2W_1\Lambda_6 - 1)/(W_1\Lambda_4\lambda_5)$ ($=2$ whenever
//!   $\rho^s_\infty = 0$). The other two Schur–Cohn conditions of the cubic do not bind for the
//!   parameter families of this module: `tests/it/gs4.rs` checks the closed form against a
//!   spectral-radius bisection ([`Gs4Params::omega_crit_bisection`], the `gs4_check.py`
//!   algorithm) over a grid of $(\rho_\infty, \rho^s_\infty, \zeta)$.

use thiserror::Error;

/// Error returned by [`Gs4Params::new`] when $(\rho_\infty, \rho^s_\infty)$ is not admissible.
///
/// The admissible set is $0 \le \rho^s_\infty \le \rho_\infty \le 1$, both finite (ALGORITHM.md §1.1).
#[derive(Clone, Copy, Debug, PartialEq, Error)]
pub enum Gs4Error {
    /// A parameter is NaN or infinite.
    #[error("GS4 parameter {name} = {value} is not finite; it must be a finite number in [0, 1]")]
    NotFinite {
        /// Parameter name (`"rho_inf"` or `"rho_s"`).
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// $\rho_\infty \notin \[0, 1\]$.
    #[error("GS4 parameter rho_inf = {0} violates 0 <= rho_inf <= 1")]
    RhoInfOutOfRange(f64),
    /// $\rho^s_\infty \notin \[0, \rho_\infty\]$.
    #[error("GS4 parameter rho_s = {rho_s} violates 0 <= rho_s <= rho_inf (rho_inf = {rho_inf})")]
    RhoSOutOfRange {
        /// The offending $\rho^s_\infty$.
        rho_s: f64,
        /// The (valid) $\rho_\infty$ it was compared with.
        rho_inf: f64,
    },
}

/// The GS4 algorithmic parameters of ALGORITHM.md §1.1, all dimensionless.
///
/// The time-weighted products $W_k\Lambda_j$ are stored as single numbers (they only ever appear
/// as products). Build with [`Gs4Params::new`]; the fields are public for reading — changing them by
/// hand voids the properties documented here (the stability-limit formulas themselves are written
/// for arbitrary field values, but only validated for the §1.1 family).
///
/// For the implicit first-order scheme, $\rho_\infty$ and $\rho^s_\infty$ are the spectral radii of
/// the amplification matrix at $k\Delta t\to\infty$ (principal and spurious root).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gs4Params {
    /// $\rho_\infty \in \[0, 1\]$: user-specified high-frequency spectral radius (principal root).
    pub rho_inf: f64,
    /// $\rho^s_\infty \in \[0, \rho_\infty\]$: high-frequency spectral radius of the spurious root.
    pub rho_s: f64,
    /// $W_1 = 1/(1+\rho_\infty)$: the forcing weight; external forces are evaluated at
    /// $t_n + W_1\Delta t$.
    pub w1: f64,
    /// $W_1\Lambda_1 = 1/(1+\rho_\infty)$: weight of $\Delta t\,v_n$ in the predicted position $\tilde x$.
    pub w1l1: f64,
    /// $W_1\Lambda_4 = 1/(1+\rho_\infty)$: weight of $\Delta t\,\dot y_n$ in the predictor $\hat y$
    /// (GS4-1) and of $\Delta t\,a_n$ in $\tilde v$ (GS4-II).
    pub w1l4: f64,
    /// $W_1\Lambda_6 = \frac{3+\rho_\infty+\rho^s_\infty-\rho_\infty\rho^s_\infty}{2(1+\rho_\infty)(1+\rho^s_\infty)}$:
    /// the "effective mass" factor multiplying the rate increment $\Delta\dot y$ / $\Delta a$.
    pub w1l6: f64,
    /// $W_2\Lambda_2 = \frac12 W_1\Lambda_4$: weight of $\Delta t^2 a_n$ in $\tilde x$.
    pub w2l2: f64,
    /// $W_2\Lambda_5 = \frac{1}{(1+\rho_\infty)(1+\rho^s_\infty)}$: implicit weight of
    /// $\Delta t\,\Delta\dot y$ in $\tilde y$ / of $\Delta t\,\Delta a$ in $\tilde v$ (only used with $\eta=1$).
    pub w2l5: f64,
    /// $W_3\Lambda_3 = \frac12 W_2\Lambda_5$: implicit weight of $\Delta t^2\Delta a$ in $\tilde x$
    /// (only used with $\eta=1$).
    pub w3l3: f64,
    /// $\lambda_1 = 1$: weight of $\Delta t\,v_n$ in $x_{n+1}$.
    pub l1: f64,
    /// $\lambda_2 = \frac12$: weight of $\Delta t^2 a_n$ in $x_{n+1}$.
    pub l2: f64,
    /// $\lambda_3 = \frac12\lambda_5 = \frac{1}{2(1+\rho^s_\infty)}$ (erratum E1 corrected): weight
    /// of $\Delta t^2\Delta a$ in $x_{n+1}$.
    pub l3: f64,
    /// $\lambda_4 = 1$: weight of $\Delta t\,\dot y_n$ in $y_{n+1}$ / of $\Delta t\,a_n$ in $v_{n+1}$.
    pub l4: f64,
    /// $\lambda_5 = \frac{1}{1+\rho^s_\infty}$: weight of $\Delta t\,\Delta\dot y$ in $y_{n+1}$ /
    /// of $\Delta t\,\Delta a$ in $v_{n+1}$.
    pub l5: f64,
}

impl Default for Gs4Params {
    /// $(\rho_\infty, \rho^s_\infty) = (0.5, 0)$, the recommended explicit default of ALGORITHM.md
    /// §1.3 ($z_{crit} = 8/7 \approx 1.143$, $\Omega_{crit} = \sqrt2$).
    fn default() -> Self {
        Self::new(0.5, 0.0).expect("(0.5, 0) is a valid GS4 parameter pair")
    }
}

impl Gs4Params {
    /// Parameters for $(\rho_\infty, \rho^s_\infty)$ per ALGORITHM.md §1.1 (with $\lambda_3 = \lambda_5/2$).
    ///
    /// Special cases: $(1,1)$ = Crank–Nicolson/trapezoid, $(0,0)$ = Gear/BDF2 (both for the implicit
    /// scheme; $(1,1)$ must not be used explicitly, see [`Gs4Params::z_crit`]).
    ///
    /// # Errors
    /// [`Gs4Error`] unless both are finite and $0 \le \rho^s_\infty \le \rho_\infty \le 1$.
    pub fn new(rho_inf: f64, rho_s: f64) -> Result<Self, Gs4Error> {
        validate(rho_inf, rho_s)?;
        Ok(Self::build(rho_inf, rho_s, false))
    }

    /// Parameters with the paper's **printed** (wrong) $\lambda_3 = 1/\lambda_5 = 1 + \rho^s_\infty$
    /// (eq. (46) of \[Su21\], erratum E1). Everything else is as in [`Gs4Params::new`].
    ///
    /// Do not use for simulation: the implicit GS4-II amplification matrix then has spectral radius
    /// up to 18 at high $\Omega$ and the position update loses the identity (1.1). It exists only
    /// so that tests can document why the correction matters.
    ///
    /// # Errors
    /// As [`Gs4Params::new`].
    pub fn paper_printed_lambda3(rho_inf: f64, rho_s: f64) -> Result<Self, Gs4Error> {
        validate(rho_inf, rho_s)?;
        Ok(Self::build(rho_inf, rho_s, true))
    }

    fn build(ri: f64, rs: f64, paper_lambda3: bool) -> Self {
        // Same operation order as gs4_check.py::params.
        let w1 = 1.0 / (1.0 + ri);
        let w1l6 = (3.0 + ri + rs - ri * rs) / (2.0 * (1.0 + ri) * (1.0 + rs));
        let w1l4 = 1.0 / (1.0 + ri);
        let w2l5 = 1.0 / ((1.0 + ri) * (1.0 + rs));
        let w1l1 = w1l4;
        let w2l2 = w1l4 / 2.0;
        let w3l3 = w2l5 / 2.0;
        let l5 = 1.0 / (1.0 + rs);
        let l3 = if paper_lambda3 { 1.0 / l5 } else { l5 / 2.0 };
        Self {
            rho_inf: ri,
            rho_s: rs,
            w1,
            w1l1,
            w1l4,
            w1l6,
            w2l2,
            w2l5,
            w3l3,
            l1: 1.0,
            l2: 0.5,
            l3,
            l4: 1.0,
            l5,
        }
    }

    /// GS4-1 amplification matrix for $\dot y = -k y$ at $z = k\Delta t \ge 0$.
    ///
    /// State vector $s = (y, \Delta t\,\dot y)$; one step is $s_{n+1} = A s_n$ (row-major
    /// `[row][col]`). `implicit = true` is eq. (1.2) with $\eta = 1$ (equivalently (1.3) with
    /// $K = k$), `false` is the explicit scheme ($\eta = 0$). Built column by column exactly as
    /// `gs4_check.py::amp1`.
    pub fn amplification_first_order(&self, z: f64, implicit: bool) -> [[f64; 2]; 2] {
        let mut a = [[0.0; 2]; 2];
        for (j, (y, hyd)) in [(1.0, 0.0), (0.0, 1.0)].into_iter().enumerate() {
            let num = hyd + z * y + z * self.w1l4 * hyd;
            let den = if implicit {
                self.w1l6 + z * self.w2l5
            } else {
                self.w1l6
            };
            let hd = -num / den;
            a[0][j] = y + self.l4 * hyd + self.l5 * hd;
            a[1][j] = hyd + hd;
        }
        a
    }

    /// GS4-II amplification matrix for $\ddot x + 2\zeta\omega\dot x + \omega^2 x = 0$ at
    /// $\Omega = \omega\Delta t \ge 0$ and damping ratio $\zeta \ge 0$.
    ///
    /// State vector $s = (x, \Delta t\,v, \Delta t^2 a)$; one step is $s_{n+1} = A s_n$
    /// (row-major). `implicit = true` is eq. (1.4) with $\eta = 1$; `false` is the explicit
    /// "eq. 36 style" scheme of \[Su21\] §6.1.1: forces at the explicit predictor
    /// $(\tilde x, \tilde v)$, effective mass $W_1\Lambda_6$ only. Built exactly as
    /// `gs4_check.py::amp2`.
    pub fn amplification_second_order(
        &self,
        omega_dt: f64,
        zeta: f64,
        implicit: bool,
    ) -> [[f64; 3]; 3] {
        let k = omega_dt * omega_dt;
        let c = 2.0 * zeta * omega_dt;
        let mut a = [[0.0; 3]; 3];
        for j in 0..3 {
            let mut e = [0.0; 3];
            e[j] = 1.0;
            let [x, hv, h2a] = e;
            let rhs =
                -(h2a + c * (hv + self.w1l4 * h2a) + k * (x + self.w1l1 * hv + self.w2l2 * h2a));
            let den = if implicit {
                self.w1l6 + c * self.w2l5 + k * self.w3l3
            } else {
                self.w1l6
            };
            let h2d = rhs / den;
            a[0][j] = x + self.l1 * hv + self.l2 * h2a + self.l3 * h2d;
            a[1][j] = hv + self.l4 * h2a + self.l5 * h2d;
            a[2][j] = h2a + h2d;
        }
        a
    }

    /// Largest stable $z = k\Delta t$ of the **explicit** GS4-1 scheme for $\dot y = -k y$
    /// (spectral radius of [`Gs4Params::amplification_first_order`] $\le 1$ for all
    /// $z \in \[0, z_{crit}\]$).
    ///
    /// Closed form (exact): the Schur–Cohn conditions $p(1)\ge0$, $p(-1)\ge0$, $|\det A|\le1$ are
    /// affine in $z$, and for the §1.1 family the binding one is $p(-1)\ge0$:
    /// $z_{crit} = (4W_1\Lambda_6-2)/(2\lambda_5+2W_1\Lambda_4-\lambda_4)$.
    /// Returns `0.0` when the scheme is unstable for every $z > 0$ (only $(1,1)$, whose spurious root
    /// is $\approx -(1+z)$), and `f64::INFINITY` if it were unconditionally stable (never for the
    /// explicit scheme with §1.1 parameters). Table of ALGORITHM.md §1.3, e.g. $(0,0)$: $4/3$,
    /// $(0.5,0)$: $8/7$, $(1,0)$: $1$.
    pub fn z_crit(&self) -> f64 {
        let m = self.w1l6;
        let t = self.l4 - self.l5 - self.w1l4;
        // m * (Jury expression) = alpha + beta * z >= 0 must hold on [0, z_crit].
        let constraints = [
            (0.0, self.l4),                                             // m p(1)
            (4.0 * m - 2.0, self.l4 - 2.0 * self.l5 - 2.0 * self.w1l4), // m p(-1)
            (1.0, -t),                                                  // m (1 - det)
            (2.0 * m - 1.0, t),                                         // m (1 + det)
        ];
        if m.is_nan() || m <= 0.0 {
            return 0.0;
        }
        let mut zc = f64::INFINITY;
        for (alpha, beta) in constraints {
            if alpha < 0.0 {
                return 0.0;
            }
            if beta < 0.0 {
                zc = zc.min(alpha / -beta);
            }
        }
        zc
    }

    /// Largest stable $\Omega = \omega\Delta t$ of the **explicit** GS4-II scheme ("eq. 36 style")
    /// for $\ddot x + 2\zeta\omega\dot x + \omega^2 x = 0$ with damping ratio `zeta` $= \zeta \ge 0$.
    ///
    /// Closed form: the positive root of $\alpha\Omega^2 + 2\zeta\beta\Omega = 8W_1\Lambda_6-4$
    /// (the $p(-1)=0$ boundary; see the module docs), evaluated without cancellation, so it is
    /// accurate also for $\zeta\to\infty$ where $\Omega_{crit}\to z_{crit}/(2\zeta)$.
    /// ALGORITHM.md §1.3: $\Omega_{crit}(\zeta=0) = \sqrt2$ for every $(\rho_\infty, 0)$,
    /// $\sqrt{2(1-\rho^s_\infty)}$ for $\rho_\infty=1$, $1.225$ for $(0.5,0.5)$, and `0.0` for
    /// $(1,1)$ (explicit scheme unusable). `zeta = +inf` gives `0.0`.
    ///
    /// # Panics
    /// If `zeta` is NaN or negative.
    pub fn omega_crit(&self, zeta: f64) -> f64 {
        assert!(
            zeta >= 0.0,
            "omega_crit: damping ratio zeta = {zeta} must be >= 0"
        );
        let (l1, l2, l3, l4, l5) = (self.l1, self.l2, self.l3, self.l4, self.l5);
        let gamma = 8.0 * self.w1l6 - 4.0;
        let beta_c = 4.0 * l5 + 4.0 * self.w1l4 - 2.0 * l4;
        let alpha = l1 * l4 - 2.0 * l1 * l5 - 2.0 * l2 + 4.0 * l3 - 2.0 * l4 * self.w1l1
            + 4.0 * l5 * self.w1l1
            + 4.0 * self.w2l2;
        if zeta.is_infinite() {
            return if beta_c > 0.0 && gamma >= 0.0 {
                0.0
            } else {
                f64::INFINITY
            };
        }
        largest_root_interval(gamma, 2.0 * zeta * beta_c, alpha)
    }

    /// Reference implementation of [`Gs4Params::z_crit`] by bisection on
    /// [`spectral_radius_2x2`] of the explicit amplification matrix (the `gs4_check.py::crit_z1`
    /// algorithm, tolerance $\rho \le 1 + 10^{-12}$). Slower (~100 matrix evaluations) and only
    /// accurate to the tolerance; used to cross-check the closed form. Assumes the stable set is
    /// an interval $\[0, z_{crit}\]$. Returns `f64::INFINITY` if still stable at $z = 10^6$.
    /// For $(1,1)$ it returns a tiny positive number ($\approx10^{-12}$) instead of 0 because of the
    /// tolerance.
    pub fn z_crit_bisection(&self) -> f64 {
        bisect_limit(|z| {
            spectral_radius_2x2(self.amplification_first_order(z, false)) <= 1.0 + 1e-12
        })
    }

    /// Reference implementation of [`Gs4Params::omega_crit`] by bisection on
    /// [`spectral_radius_3x3`] of the explicit amplification matrix (the `gs4_check.py::crit_Om`
    /// algorithm, tolerance $\rho \le 1 + 10^{-10}$). Same caveats as
    /// [`Gs4Params::z_crit_bisection`]; for $(1,1)$ it returns $\approx10^{-5}$ instead of 0.
    pub fn omega_crit_bisection(&self, zeta: f64) -> f64 {
        bisect_limit(|om| {
            spectral_radius_3x3(self.amplification_second_order(om, zeta, false)) <= 1.0 + 1e-10
        })
    }

    /// Advances a GS4-1 state given the rate increment $\Delta\dot y$ (ALGORITHM.md §1.2):
    /// $y_{n+1} = y_n + \lambda_4\Delta t\,\dot y_n + \lambda_5\Delta t\,\Delta\dot y$,
    /// $\dot y_{n+1} = \dot y_n + \Delta\dot y$.
    pub fn advance_first_order(
        &self,
        s: &FirstOrderState,
        dt: f64,
        delta_ydot: f64,
    ) -> FirstOrderState {
        FirstOrderState {
            y: s.y + self.l4 * dt * s.ydot + self.l5 * dt * delta_ydot,
            ydot: s.ydot + delta_ydot,
        }
    }

    /// Advances a GS4-II state given the acceleration increment $\Delta a$ (last line of eq. (1.4)):
    /// $x_{n+1} = x_n + \lambda_1\Delta t v_n + \lambda_2\Delta t^2 a_n + \lambda_3\Delta t^2\Delta a$,
    /// $v_{n+1} = v_n + \lambda_4\Delta t a_n + \lambda_5\Delta t\Delta a$, $a_{n+1} = a_n + \Delta a$.
    /// With §1.1 parameters this satisfies $x_{n+1} = x_n + \frac{\Delta t}{2}(v_n + v_{n+1})$ (1.1).
    pub fn advance_second_order(
        &self,
        s: &SecondOrderState,
        dt: f64,
        delta_a: f64,
    ) -> SecondOrderState {
        let dt2 = dt * dt;
        SecondOrderState {
            x: s.x + self.l1 * dt * s.v + self.l2 * dt2 * s.a + self.l3 * dt2 * delta_a,
            v: s.v + self.l4 * dt * s.a + self.l5 * dt * delta_a,
            a: s.a + delta_a,
        }
    }
}

fn validate(rho_inf: f64, rho_s: f64) -> Result<(), Gs4Error> {
    if !rho_inf.is_finite() {
        return Err(Gs4Error::NotFinite {
            name: "rho_inf",
            value: rho_inf,
        });
    }
    if !rho_s.is_finite() {
        return Err(Gs4Error::NotFinite {
            name: "rho_s",
            value: rho_s,
        });
    }
    if !(0.0..=1.0).contains(&rho_inf) {
        return Err(Gs4Error::RhoInfOutOfRange(rho_inf));
    }
    if !(0.0..=rho_inf).contains(&rho_s) {
        return Err(Gs4Error::RhoSOutOfRange { rho_s, rho_inf });
    }
    Ok(())
}

/// Largest $X \ge 0$ such that $f(x) = \gamma - \beta x - \alpha x^2 \ge 0$ on all of $\[0, X\]$
/// (`0.0` if $\gamma < 0$, `INFINITY` if never violated). Cancellation-free root formulas.
fn largest_root_interval(gamma: f64, beta: f64, alpha: f64) -> f64 {
    if gamma.is_nan() || gamma < 0.0 {
        return 0.0;
    }
    if alpha > 0.0 {
        // One positive root of alpha x^2 + beta x - gamma.
        let disc = (beta * beta + 4.0 * alpha * gamma).sqrt();
        if beta >= 0.0 {
            let den = beta + disc;
            if den > 0.0 { 2.0 * gamma / den } else { 0.0 }
        } else {
            (-beta + disc) / (2.0 * alpha)
        }
    } else if alpha == 0.0 {
        if beta > 0.0 {
            gamma / beta
        } else {
            f64::INFINITY
        }
    } else {
        // f = gamma - beta x + |alpha| x^2: convex; violated only if beta > 0 and real roots.
        let a = -alpha;
        if beta <= 0.0 {
            return f64::INFINITY;
        }
        let d = beta * beta - 4.0 * a * gamma;
        if d < 0.0 {
            f64::INFINITY
        } else {
            2.0 * gamma / (beta + d.sqrt())
        }
    }
}

/// Bisection for the boundary of a stable set assumed to be $\[0, X\]$: bracket by doubling from 1
/// (up to $10^6$, else infinity), then 200 halvings.
fn bisect_limit(stable: impl Fn(f64) -> bool) -> f64 {
    let mut lo = 0.0;
    let mut hi = 1.0;
    while stable(hi) {
        lo = hi;
        hi *= 2.0;
        if hi > 1e6 {
            return f64::INFINITY;
        }
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if stable(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// Largest absolute entry of a matrix (used to scale before forming products).
fn max_abs<const N: usize>(m: &[[f64; N]; N]) -> f64 {
    m.iter().flatten().fold(0.0_f64, |acc, v| acc.max(v.abs()))
}

/// Eigenvalues of a real 2×2 matrix (row-major), as `(re, im)` pairs; a complex pair is returned
/// as $(t, +s), (t, -s)$. Real eigenvalues: the larger-magnitude one first, the other from
/// $\det/\lambda_1$ (no cancellation). The matrix is scaled by its largest entry first, so
/// entries up to the `f64` range do not overflow; non-finite input gives NaN.
pub fn eigenvalues_2x2(m: [[f64; 2]; 2]) -> [(f64, f64); 2] {
    let sc = max_abs(&m);
    if sc == 0.0 {
        return [(0.0, 0.0); 2];
    }
    if !sc.is_finite() {
        return [(f64::NAN, f64::NAN); 2];
    }
    let m = m.map(|row| row.map(|v| v / sc));
    let t = 0.5 * (m[0][0] + m[1][1]);
    let h = 0.5 * (m[0][0] - m[1][1]);
    let d = h * h + m[0][1] * m[1][0];
    if d >= 0.0 {
        let sq = d.sqrt();
        let l1 = t + sq.copysign(t);
        let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
        let l2 = if l1 != 0.0 { det / l1 } else { 0.0 };
        [(l1 * sc, 0.0), (l2 * sc, 0.0)]
    } else {
        let s = (-d).sqrt();
        [(t * sc, s * sc), (t * sc, -s * sc)]
    }
}

/// Spectral radius $\max_i|\lambda_i|$ of a real 2×2 matrix (row-major; complex eigenvalues
/// allowed). With $t = \operatorname{tr}/2$ and $d = ((a_{00}-a_{11})/2)^2 + a_{01}a_{10}$ (after
/// scaling by the largest entry): real case $|t| + \sqrt{d}$, complex case $\sqrt{t^2 - d}$.
pub fn spectral_radius_2x2(m: [[f64; 2]; 2]) -> f64 {
    let sc = max_abs(&m);
    if sc == 0.0 || !sc.is_finite() {
        return if sc == 0.0 { 0.0 } else { f64::NAN };
    }
    let m = m.map(|row| row.map(|v| v / sc));
    let t = 0.5 * (m[0][0] + m[1][1]);
    let h = 0.5 * (m[0][0] - m[1][1]);
    let d = h * h + m[0][1] * m[1][0];
    sc * if d >= 0.0 {
        t.abs() + d.sqrt()
    } else {
        (t * t - d).sqrt()
    }
}

/// Eigenvalues of a real 3×3 matrix (row-major) as `(re, im)` pairs, in no particular order
/// (a complex pair appears as $(t, +s), (t, -s)$).
///
/// Method (backward stable): scale by the largest entry; reduce to Hessenberg form with one
/// Parlett–Reinsch balancing by exact powers of two: a diagonal similarity that makes the
/// off-diagonal row and column norms comparable, which reduces the eigenvalue sensitivity of the
/// strongly non-normal amplification matrices (entries from ~1e-7 to ~10 at high Ω).
fn balance(h: &mut [[f64; 3]; 3]) {
    for _ in 0..32 {
        let mut changed = false;
        for i in 0..3 {
            let (j, k) = ((i + 1) % 3, (i + 2) % 3);
            let c = h[j][i].abs() + h[k][i].abs();
            let r = h[i][j].abs() + h[i][k].abs();
            if c == 0.0 || r == 0.0 {
                continue;
            }
            let mut f = 1.0;
            let (mut cc, s) = (c, c + r);
            while cc < r / 2.0 {
                cc *= 2.0;
                f *= 2.0;
            }
            while cc > r * 2.0 {
                cc /= 2.0;
                f /= 2.0;
            }
            // cc = c·f; new norms c·f and r/f.
            if cc + r / f < 0.95 * s {
                changed = true;
                for row in h.iter_mut() {
                    row[i] *= f;
                }
                for v in h[i].iter_mut() {
                    *v /= f;
                }
            }
        }
        if !changed {
            break;
        }
    }
}

/// Givens rotation; run real single-shift QR steps until a subdiagonal entry is negligible
/// ($\le\epsilon(|h_{ii}|+|h_{jj}|)$), which splits off one real eigenvalue and leaves a 2×2 block
/// solved by [`eigenvalues_2x2`]. The first shift is a real root of the characteristic cubic
/// $\lambda^3 + c_2\lambda^2 + c_1\lambda + c_0$ (trigonometric / Cardano formula polished by
/// Newton steps; a real 3×3 matrix always has one real eigenvalue), later shifts are the Rayleigh
/// quotient $h_{22}$, so convergence takes a few steps. If it ever failed (60 steps), the roots of
/// the cubic are returned instead.
///
/// Why not just the cubic: its coefficients (trace, minors, determinant) carry rounding errors
/// that move clustered roots by $\sim\epsilon/\delta^2$ (cluster spread $\delta$); e.g. the
/// implicit GS4-II matrix at $(1,1)$, $\Omega\approx7\cdot10^3$, $\zeta=0.05$ (roots $-1$ and
/// $0.99997\,e^{\pm i\theta}$) came out with $|\lambda| = 1 + 1.6\cdot10^{-9}$; the QR refinement
/// gives $1 + O(\epsilon)$. Non-finite input gives NaN.
pub fn eigenvalues_3x3(m: [[f64; 3]; 3]) -> [(f64, f64); 3] {
    let sc = max_abs(&m);
    if sc == 0.0 {
        return [(0.0, 0.0); 3];
    }
    if !sc.is_finite() {
        return [(f64::NAN, f64::NAN); 3];
    }
    let mut h = m.map(|row| row.map(|v| v / sc));
    let unscale = |e: [(f64, f64); 3]| e.map(|(re, im)| (re * sc, im * sc));

    // Isolation (as LAPACK's balancing does): a row or column whose off-diagonal entries are all
    // zero makes the matrix block-triangular up to a permutation, so its diagonal entry is an
    // exact eigenvalue and the rest is a 2×2 problem. This keeps exact structure (e.g. the
    // implicit (1,1) GS4-II matrix, whose third column is exactly (0, 0, −1)) exact.
    for i in 0..3 {
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        let col_zero = h[j][i] == 0.0 && h[k][i] == 0.0;
        let row_zero = h[i][j] == 0.0 && h[i][k] == 0.0;
        if col_zero || row_zero {
            let (p, q) = (j.min(k), j.max(k));
            let e = eigenvalues_2x2([[h[p][p], h[p][q]], [h[q][p], h[q][q]]]);
            return unscale([(h[i][i], 0.0), e[0], e[1]]);
        }
    }
    balance(&mut h);

    // Hessenberg form: rotate in the (1, 2) plane to zero h[2][0].
    let (c, s) = givens(h[1][0], h[2][0]);
    rotate_rows(&mut h, 1, c, s);
    rotate_cols(&mut h, 1, c, s);
    h[2][0] = 0.0;

    let roots = charpoly_roots(&h);
    let mut mu = roots.iter().find(|r| r.1 == 0.0).map_or(h[2][2], |r| r.0);
    let negligible = |sub: f64, d1: f64, d2: f64| {
        let scale = d1.abs() + d2.abs();
        sub.abs() <= f64::EPSILON * if scale > 0.0 { scale } else { 1.0 }
    };
    for it in 0..60 {
        if negligible(h[2][1], h[1][1], h[2][2]) {
            let e = eigenvalues_2x2([[h[0][0], h[0][1]], [h[1][0], h[1][1]]]);
            return unscale([(h[2][2], 0.0), e[0], e[1]]);
        }
        if negligible(h[1][0], h[0][0], h[1][1]) {
            let e = eigenvalues_2x2([[h[1][1], h[1][2]], [h[2][1], h[2][2]]]);
            return unscale([(h[0][0], 0.0), e[0], e[1]]);
        }
        qr_step(&mut h, mu);
        mu = if it % 20 == 19 {
            // exceptional shift against (unlikely) cycling
            h[2][2] + 0.75 * h[2][1].abs()
        } else {
            h[2][2]
        };
    }
    unscale(roots)
}

/// Spectral radius $\max_i|\lambda_i|$ of a real 3×3 matrix (row-major; complex eigenvalues
/// allowed), via [`eigenvalues_3x3`].
pub fn spectral_radius_3x3(m: [[f64; 3]; 3]) -> f64 {
    eigenvalues_3x3(m)
        .iter()
        .map(|&(re, im)| re.hypot(im))
        .fold(0.0, f64::max)
}

/// Givens rotation $(c, s)$ with $\[c\ s; -s\ c\]\,(a, b)^T = (r, 0)^T$.
fn givens(a: f64, b: f64) -> (f64, f64) {
    let r = a.hypot(b);
    if r == 0.0 { (1.0, 0.0) } else { (a / r, b / r) }
}

/// Rows (i, i+1) ← G · rows.
fn rotate_rows(h: &mut [[f64; 3]; 3], i: usize, c: f64, s: f64) {
    let (top, bottom) = h.split_at_mut(i + 1);
    for (u, w) in top[i].iter_mut().zip(bottom[0].iter_mut()) {
        let (x, y) = (*u, *w);
        *u = c * x + s * y;
        *w = -s * x + c * y;
    }
}

/// Columns (i, i+1) ← columns · Gᵀ.
fn rotate_cols(h: &mut [[f64; 3]; 3], i: usize, c: f64, s: f64) {
    for row in h.iter_mut() {
        let (x, y) = (row[i], row[i + 1]);
        row[i] = c * x + s * y;
        row[i + 1] = -s * x + c * y;
    }
}

/// One shifted QR step $H - \mu I = QR$, $H \leftarrow RQ + \mu I$ on a 3×3 Hessenberg matrix.
fn qr_step(h: &mut [[f64; 3]; 3], mu: f64) {
    for (i, row) in h.iter_mut().enumerate() {
        row[i] -= mu;
    }
    let (c1, s1) = givens(h[0][0], h[1][0]);
    rotate_rows(h, 0, c1, s1);
    h[1][0] = 0.0;
    let (c2, s2) = givens(h[1][1], h[2][1]);
    rotate_rows(h, 1, c2, s2);
    h[2][1] = 0.0;
    rotate_cols(h, 0, c1, s1);
    rotate_cols(h, 1, c2, s2);
    h[2][0] = 0.0;
    for (i, row) in h.iter_mut().enumerate() {
        row[i] += mu;
    }
}

/// Roots of the characteristic polynomial of `a` (entries of moderate size).
fn charpoly_roots(a: &[[f64; 3]; 3]) -> [(f64, f64); 3] {
    let tr = a[0][0] + a[1][1] + a[2][2];
    let minors = a[0][0] * a[1][1] - a[0][1] * a[1][0] + a[0][0] * a[2][2] - a[0][2] * a[2][0]
        + a[1][1] * a[2][2]
        - a[1][2] * a[2][1];
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    cubic_roots(-tr, minors, -det)
}

/// Roots of $\lambda^3 + a\lambda^2 + b\lambda + c$ (coefficients of moderate size).
fn cubic_roots(a: f64, b: f64, c: f64) -> [(f64, f64); 3] {
    let p = |x: f64| ((x + a) * x + b) * x + c;
    let polish = |mut x: f64| {
        let mut px = p(x);
        for _ in 0..4 {
            if px == 0.0 {
                break;
            }
            let dp = (3.0 * x + 2.0 * a) * x + b;
            if dp == 0.0 {
                break;
            }
            let xn = x - px / dp;
            let pn = p(xn);
            if pn.abs() < px.abs() {
                x = xn;
                px = pn;
            } else {
                break;
            }
        }
        x
    };
    let q = (a * a - 3.0 * b) / 9.0;
    let r = (2.0 * a * a * a - 9.0 * a * b + 27.0 * c) / 54.0;
    let q3 = q * q * q;
    if r * r < q3 {
        // Three real roots (trigonometric form).
        let sq = q.sqrt();
        let theta = (r / (sq * sq * sq)).clamp(-1.0, 1.0).acos();
        let tau = 2.0 * std::f64::consts::PI / 3.0;
        let mut out = [(0.0, 0.0); 3];
        for (k, o) in out.iter_mut().enumerate() {
            let x = -2.0 * sq * (theta / 3.0 + tau * k as f64).cos() - a / 3.0;
            *o = (polish(x), 0.0);
        }
        return out;
    }
    // One real root for sure (Cardano), then deflate.
    let big_a = -(r.abs() + (r * r - q3).sqrt()).cbrt().copysign(r);
    let big_b = if big_a != 0.0 { q / big_a } else { 0.0 };
    let x = polish(big_a + big_b - a / 3.0);
    // Quadratic lambda^2 + q1 lambda + q0 with the remaining two roots.
    let q1 = a + x;
    let q0 = if x != 0.0 && x.abs().powi(3) < c.abs() {
        -c / x
    } else {
        b + x * q1
    };
    let t = -0.5 * q1;
    let d = t * t - q0;
    if d >= 0.0 {
        let sq = d.sqrt();
        let u = t + sq.copysign(t);
        let v = if u != 0.0 { q0 / u } else { 0.0 };
        [(x, 0.0), (u, 0.0), (v, 0.0)]
    } else {
        let s = (-d).sqrt();
        [(x, 0.0), (t, s), (t, -s)]
    }
}

/// State of a scalar GS4-1 field: value $y$ and its rate $\dot y$ (units of $y$ per second).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FirstOrderState {
    /// Value $y_n$.
    pub y: f64,
    /// Rate $\dot y_n$ \[units of y · s⁻¹\]; must be initialised consistently, e.g. $\dot y_0 = g(y_0, t_0)$.
    pub ydot: f64,
}

/// State of a scalar GS4-II system: position, velocity and acceleration.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SecondOrderState {
    /// Position $x_n$ \[m, or any unit X\].
    pub x: f64,
    /// Velocity $v_n$ \[X s⁻¹\].
    pub v: f64,
    /// Acceleration $a_n$ \[X s⁻²\], the GS4 rate of $v$; initialise with $a_0 = f(x_0, v_0, t_0)$.
    pub a: f64,
}

/// One GS4-1 step (ALGORITHM.md §1.2, eq. (1.2)/(1.3)) of $\dot y = g(y, t)$ from $t$ to
/// $t + \Delta t$ (`dt` \[s\]).
///
/// * Predictor $\hat y = y_n + W_1\Lambda_4\Delta t\,\dot y_n$; `g` is called once, as
///   `g(ŷ, t + W₁Δt)`, and must return the **full** rate $g(\hat y)$.
/// * `stiffness = None`: explicit ($\eta = 0$), $\Delta\dot y = (g(\hat y) - \dot y_n)/W_1\Lambda_6$.
///   Stable for $-\partial g/\partial y \cdot \Delta t \le$ [`Gs4Params::z_crit`].
/// * `stiffness = Some(K)`: linearly implicit ($\eta = 1$, eq. (1.3)) for $g(y) = -K y + h(y)$ with
///   $K \ge 0$ \[s⁻¹\] frozen: $\Delta\dot y = (g(\hat y) - \dot y_n)/(W_1\Lambda_6 + W_2\Lambda_5\Delta t K)$.
///   For linear $g = -K y$ this is exactly the implicit GS4-1 scheme (A-stable).
///
/// Then $y_{n+1} = y_n + \lambda_4\Delta t\dot y_n + \lambda_5\Delta t\Delta\dot y$,
/// $\dot y_{n+1} = \dot y_n + \Delta\dot y$. Returns the algorithmic value
/// $\tilde y = \hat y + \eta W_2\Lambda_5\Delta t\,\Delta\dot y$ at $t_n + W_1\Delta t$.
pub fn step_first_order(
    p: &Gs4Params,
    s: &mut FirstOrderState,
    t: f64,
    dt: f64,
    stiffness: Option<f64>,
    g: impl FnOnce(f64, f64) -> f64,
) -> f64 {
    let y_hat = s.y + p.w1l4 * dt * s.ydot;
    let rate = g(y_hat, t + p.w1 * dt);
    let (den, eta) = match stiffness {
        None => (p.w1l6, 0.0),
        Some(k) => (p.w1l6 + p.w2l5 * dt * k, 1.0),
    };
    let d = (rate - s.ydot) / den;
    *s = p.advance_first_order(s, dt, d);
    y_hat + eta * p.w2l5 * dt * d
}

/// One explicit GS4-II step (eq. (1.4) with $\eta = 0$, \[Su21\] §6.1.1) of $\ddot x = f(x, v, t)$
/// from $t$ to $t + \Delta t$ (`dt` \[s\]).
///
/// `f` is called once as `f(x̃, ṽ, t + W₁Δt)` with the explicit predictor
/// $\tilde x = x_n + W_1\Lambda_1\Delta t v_n + W_2\Lambda_2\Delta t^2 a_n$,
/// $\tilde v = v_n + W_1\Lambda_4\Delta t a_n$, and returns the acceleration (force per mass);
/// then $\Delta a = (f - a_n)/W_1\Lambda_6$ and the state is advanced with
/// [`Gs4Params::advance_second_order`]. Stable for linear oscillators with
/// $\omega\Delta t \le$ [`Gs4Params::omega_crit`]$(\zeta)$.
pub fn step_second_order_explicit(
    p: &Gs4Params,
    s: &mut SecondOrderState,
    t: f64,
    dt: f64,
    f: impl FnOnce(f64, f64, f64) -> f64,
) {
    let x_t = s.x + p.w1l1 * dt * s.v + p.w2l2 * dt * dt * s.a;
    let v_t = s.v + p.w1l4 * dt * s.a;
    let acc = f(x_t, v_t, t + p.w1 * dt);
    let da = (acc - s.a) / p.w1l6;
    *s = p.advance_second_order(s, dt, da);
}

/// One implicit GS4-II step (eq. (1.4) with $\eta = 1$, solved in closed form) of the linear
/// system $\ddot x + c\dot x + k x = F(t)$ (unit mass) from $t$ to $t + \Delta t$.
///
/// `stiffness` $k = \omega^2$ \[s⁻²\], `damping` $c = 2\zeta\omega$ \[s⁻¹\], `forcing` $F$ \[X s⁻²\]
/// is evaluated once at $t + W_1\Delta t$:
/// $\Delta a = \dfrac{F - a_n - c(v_n + W_1\Lambda_4\Delta t a_n) -
/// k(x_n + W_1\Lambda_1\Delta t v_n + W_2\Lambda_2\Delta t^2 a_n)}{W_1\Lambda_6 +
/// c W_2\Lambda_5\Delta t + k W_3\Lambda_3\Delta t^2}$.
pub fn step_second_order_linear_implicit(
    p: &Gs4Params,
    s: &mut SecondOrderState,
    t: f64,
    dt: f64,
    stiffness: f64,
    damping: f64,
    forcing: impl FnOnce(f64) -> f64,
) {
    let dt2 = dt * dt;
    let f_ext = forcing(t + p.w1 * dt);
    let num = f_ext
        - s.a
        - damping * (s.v + p.w1l4 * dt * s.a)
        - stiffness * (s.x + p.w1l1 * dt * s.v + p.w2l2 * dt2 * s.a);
    let den = p.w1l6 + damping * p.w2l5 * dt + stiffness * p.w3l3 * dt2;
    let da = num / den;
    *s = p.advance_second_order(s, dt, da);
}

/// Largest θ·z_max for which the transfer-consistent predictors of the semi-implicit solves
/// (implicit viscosity with [`FlipUpdate::ParticleGs4`](crate::config::FlipUpdate::ParticleGs4),
/// [`crate::step::implicit::viscous::implicit_viscous_update`]; the heat solve,
/// [`crate::thermal::systems::thermal_solve`]) are applied; θ = W₂Λ₅Δt/W₁Λ₆ and z_max the
/// largest decay rate of the implicit operator (8ν/Δx² for viscosity, 12k/Δx² (+ 1/τ) for heat).
///
/// The correction D = (I − PW)R⁰ is explicit in the predictor rate R⁰: a stiff mode that the
/// transfers do not reproduce is pushed by up to θz before the implicit solve, so beyond
/// θz ≈ 10 the step grows it without bound (measured with GS4 (0.5, 0): heat in
/// `fourier_slab` stable at θz_max = 8.8 and unstable at 14; the syrup cube of
/// `tests/it/integrators.rs` stable at 6.5 and unstable at 13). Up to this bound (5× margin) the
/// correction runs and the step is second order in time; above it the step is the
/// uncorrected, first-order but unconditionally stable one, which is what a step that large
/// against the stiffest mode calls for anyway.
pub const TRANSFER_CORRECTION_MAX_STIFFNESS: f64 = 2.0;
