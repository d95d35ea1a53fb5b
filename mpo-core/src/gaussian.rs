//! The policy's full-covariance Gaussian, parameterised by its Cholesky factor.
//!
//! The network's head outputs a mean (`A` values) and the lower triangle of `L` (`T = A(A+1)/2`
//! values, row by row: `(0,0), (1,0), (1,1), (2,0), ...`). The diagonal goes through a softplus
//! plus a floor so `L` stays invertible; `Sigma = L L^T`. Every density and divergence goes
//! through triangular solves, never an explicit inverse (`docs/algorithm.md`, "The policy").
//!
//! KL(old || new) splits exactly into a mean part and a covariance part (the replication report
//! swaps their names: `docs/algorithm.md`, "Where the replication report is wrong"):
//! - mean part `0.5 (mu - mu_old)^T Sigma^-1 (mu - mu_old)`;
//! - covariance part `0.5 (tr(Sigma^-1 Sigma_old) - A + ln det Sigma - ln det Sigma_old)`.
//!
//! The M-step's decoupled constraints evaluate the mean part with `Sigma = Sigma_old` (the
//! distribution `N(mu_theta, Sigma_old)`) and the covariance part with `mu = mu_old`.
//!
//! Gradients are returned with respect to `mu` and `L`, and mapped to the raw head outputs by
//! [`head_backward`]. Only the lower triangle of an `L` gradient is meaningful.

use crate::rng::Rng;

/// `ln(2 pi)`.
const LN_2PI: f32 = 1.837_877_1;

/// Index of `L[j][k]` (`k <= j`) in the packed lower triangle.
#[inline(always)]
pub const fn tri_index(j: usize, k: usize) -> usize {
    j * (j + 1) / 2 + k
}

/// Numerically stable `ln(1 + e^x)`.
#[inline]
pub fn softplus(x: f32) -> f32 {
    if x > 20.0 {
        x
    } else {
        libm::log1pf(libm::expf(x))
    }
}

/// `1 / (1 + e^-x)`, the derivative of [`softplus`].
#[inline]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + libm::expf(-x))
}

/// Inverse of [`softplus`] for positive `y` (used to initialise a head to a chosen scale).
pub fn softplus_inverse(y: f32) -> f32 {
    if y > 20.0 {
        y
    } else {
        libm::logf(libm::expm1f(y))
    }
}

/// A Gaussian `N(mu, L L^T)` over `A` action dimensions.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Zeroable)]
pub struct Gaussian<const A: usize> {
    /// Mean.
    pub mu: [f32; A],
    /// Lower-triangular Cholesky factor with a positive diagonal (zeros above the diagonal).
    pub l: [[f32; A]; A],
}

/// The two parts of KL(old || new); they sum to the full divergence.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct KlParts {
    /// `0.5 (mu - mu_old)^T Sigma^-1 (mu - mu_old)`.
    pub mean: f32,
    /// `0.5 (tr(Sigma^-1 Sigma_old) - A + ln det Sigma - ln det Sigma_old)`.
    pub cov: f32,
}

impl KlParts {
    /// The full divergence.
    pub fn total(&self) -> f32 {
        self.mean + self.cov
    }
}

/// Gradient of a scalar with respect to a Gaussian's `mu` and `L`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaussianGrad<const A: usize> {
    /// d/d mu.
    pub mu: [f32; A],
    /// d/d L (lower triangle meaningful, the rest kept at zero).
    pub l: [[f32; A]; A],
}

impl<const A: usize> GaussianGrad<A> {
    /// All zeros.
    pub const ZERO: Self = Self {
        mu: [0.0; A],
        l: [[0.0; A]; A],
    };
}

impl<const A: usize> Gaussian<A> {
    /// Builds the distribution from raw head outputs: `L_jj = softplus(raw) + floor`.
    pub fn from_head<const T: usize>(mean: &[f32; A], chol: &[f32; T], floor: f32) -> Self {
        const { assert!(T == A * (A + 1) / 2, "T must be A(A+1)/2") };
        let mut l = [[0f32; A]; A];
        for j in 0..A {
            for k in 0..j {
                l[j][k] = chol[tri_index(j, k)];
            }
            l[j][j] = softplus(chol[tri_index(j, j)]) + floor;
        }
        Self { mu: *mean, l }
    }

    /// `sum_j ln L_jj = 0.5 ln det Sigma`.
    pub fn half_log_det(&self) -> f32 {
        let mut s = 0.0;
        for j in 0..A {
            s += libm::logf(self.l[j][j]);
        }
        s
    }

    /// Draws `a = mu + L z` with `z ~ N(0, I)`.
    pub fn sample(&self, rng: &mut Rng, a: &mut [f32; A]) {
        let mut z = [0f32; A];
        rng.fill_normal(&mut z);
        self.transform(&z, a);
    }

    /// `a = mu + L z` for a given standard-normal `z`.
    pub fn transform(&self, z: &[f32; A], a: &mut [f32; A]) {
        for j in 0..A {
            let mut v = self.mu[j];
            for k in 0..=j {
                v += self.l[j][k] * z[k];
            }
            a[j] = v;
        }
    }

    /// `ln N(a; mu, L L^T)`.
    pub fn log_prob(&self, a: &[f32; A]) -> f32 {
        let z = self.whiten(a);
        let mut q = 0.0;
        for v in z {
            q += v * v;
        }
        -0.5 * q - self.half_log_det() - 0.5 * A as f32 * LN_2PI
    }

    /// `z = L^-1 (a - mu)`.
    fn whiten(&self, a: &[f32; A]) -> [f32; A] {
        let mut d = [0f32; A];
        for j in 0..A {
            d[j] = a[j] - self.mu[j];
        }
        solve_lower(&self.l, &d)
    }

    /// Adds `c * d ln N(a) / d(mu, L)` into `g`; returns `ln N(a)`.
    ///
    /// `d/d mu = L^-T z`, `d/d L_jk = (L^-T z)_j z_k - [j = k] / L_jj` with `z = L^-1 (a - mu)`.
    pub fn log_prob_grad(&self, a: &[f32; A], c: f32, g: &mut GaussianGrad<A>) -> f32 {
        let z = self.whiten(a);
        let w = solve_upper_t(&self.l, &z);
        let mut q = 0.0;
        for j in 0..A {
            q += z[j] * z[j];
            g.mu[j] += c * w[j];
            for k in 0..j {
                g.l[j][k] += c * (w[j] * z[k]);
            }
            g.l[j][j] += c * (w[j] * z[j] - 1.0 / self.l[j][j]);
        }
        -0.5 * q - self.half_log_det() - 0.5 * A as f32 * LN_2PI
    }

    /// Differential entropy `0.5 A (1 + ln 2 pi) + sum_j ln L_jj`.
    pub fn entropy(&self) -> f32 {
        0.5 * A as f32 * (1.0 + LN_2PI) + self.half_log_det()
    }

    /// Standard deviations `sqrt(Sigma_jj)` (for logging).
    pub fn std_devs(&self) -> [f32; A] {
        let mut s = [0f32; A];
        for j in 0..A {
            let mut v = 0.0;
            for k in 0..=j {
                v += self.l[j][k] * self.l[j][k];
            }
            s[j] = libm::sqrtf(v);
        }
        s
    }
}

/// The weighted action samples of one state, reduced to what the M-step's weighted
/// log-likelihood needs: with `d_j = a_j - mu_old`, the total weight `W = sum_j w_j`, the
/// weighted sum `dbar = sum_j w_j d_j` and the weighted scatter `S = sum_j w_j d_j d_j^T`.
///
/// `sum_j w_j ln N(a_j; mu, Sigma)` is then a closed form in `(W, dbar, S)`, so an M-step
/// iteration costs `O(A^3)` per state whatever the number of samples, instead of one
/// triangular solve per sample and iteration.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Zeroable)]
pub struct SampleStats<const A: usize> {
    /// `W`.
    pub w: f32,
    /// `dbar`.
    pub d: [f32; A],
    /// `S` (symmetric; both triangles filled).
    pub s: [[f32; A]; A],
}

impl<const A: usize> SampleStats<A> {
    /// No samples.
    pub const ZERO: Self = Self {
        w: 0.0,
        d: [0.0; A],
        s: [[0.0; A]; A],
    };

    /// Adds the sample `a` with weight `w` around the mean `mu_old`.
    pub fn add(&mut self, w: f32, a: &[f32; A], mu_old: &[f32; A]) {
        let mut d = [0f32; A];
        for j in 0..A {
            d[j] = a[j] - mu_old[j];
        }
        self.w += w;
        for j in 0..A {
            let wd = w * d[j];
            self.d[j] += wd;
            for k in 0..A {
                self.s[j][k] += wd * d[k];
            }
        }
    }
}

/// `V = L^-1 S L^-T` for symmetric `S` (symmetric result, both triangles).
fn whiten_scatter<const A: usize>(l: &[[f32; A]; A], s: &[[f32; A]; A]) -> [[f32; A]; A] {
    // X = L^-1 S column by column, then V = L^-1 X^T (= L^-1 S L^-T since S is symmetric).
    let mut x = [[0f32; A]; A];
    for c in 0..A {
        let mut col = [0f32; A];
        for r in 0..A {
            col[r] = s[r][c];
        }
        let y = solve_lower(l, &col);
        for r in 0..A {
            x[r][c] = y[r];
        }
    }
    let mut v = [[0f32; A]; A];
    for c in 0..A {
        let y = solve_lower(l, &x[c]);
        for r in 0..A {
            v[r][c] = y[r];
        }
    }
    v
}

/// The mean half of the decoupled M-step objective: `sum_j w_j ln N(a_j; mu, L_old L_old^T)`
/// for the samples summarised in `st` (taken around `old.mu`), adding `c` times its gradient
/// with respect to `mu` into `g.mu`. With `y = L_old^-1 (mu - mu_old)`,
/// `zbar = L_old^-1 dbar` and `c0 = tr(L_old^-1 S L_old^-T)`, the value is
/// `-0.5 (c0 - 2 y.zbar + W |y|^2) - W (ln det L_old + A ln(2 pi) / 2)` and the gradient
/// `L_old^-T (zbar - W y)`.
pub fn weighted_log_prob_mean<const A: usize>(
    old: &Gaussian<A>,
    mu: &[f32; A],
    st: &SampleStats<A>,
    c: f32,
    g: &mut GaussianGrad<A>,
) -> f32 {
    let mut delta = [0f32; A];
    for j in 0..A {
        delta[j] = mu[j] - old.mu[j];
    }
    let y = solve_lower(&old.l, &delta);
    let zbar = solve_lower(&old.l, &st.d);
    let v = whiten_scatter(&old.l, &st.s);
    let (mut c0, mut yz, mut yy) = (0f32, 0f32, 0f32);
    let mut r = [0f32; A];
    for j in 0..A {
        c0 += v[j][j];
        yz += y[j] * zbar[j];
        yy += y[j] * y[j];
        r[j] = zbar[j] - st.w * y[j];
    }
    let gm = solve_upper_t(&old.l, &r);
    for j in 0..A {
        g.mu[j] += c * gm[j];
    }
    -0.5 * (c0 - 2.0 * yz + st.w * yy) - st.w * (old.half_log_det() + 0.5 * A as f32 * LN_2PI)
}

/// The covariance half: `sum_j w_j ln N(a_j; mu_old, L L^T)` for the samples in `st` (taken
/// around `mu_old`), adding `c` times its gradient with respect to `L` into `g.l`. With
/// `V = L^-1 S L^-T` the value is `-0.5 tr V - W (ln det L + A ln(2 pi) / 2)` and the gradient
/// the lower triangle of `L^-T V - W diag(1 / L_jj)`.
pub fn weighted_log_prob_cov<const A: usize>(
    new: &Gaussian<A>,
    st: &SampleStats<A>,
    c: f32,
    g: &mut GaussianGrad<A>,
) -> f32 {
    let v = whiten_scatter(&new.l, &st.s);
    let mut tr = 0f32;
    for c2 in 0..A {
        tr += v[c2][c2];
        let p = solve_upper_t(&new.l, &v[c2]);
        // Column c2 of L^-T V (V is symmetric, so its row c2 is its column c2).
        for j in c2..A {
            g.l[j][c2] += c * p[j];
        }
    }
    for j in 0..A {
        g.l[j][j] -= c * st.w / new.l[j][j];
    }
    -0.5 * tr - st.w * (new.half_log_det() + 0.5 * A as f32 * LN_2PI)
}

/// KL(old || new) in its two parts.
pub fn kl_parts<const A: usize>(old: &Gaussian<A>, new: &Gaussian<A>) -> KlParts {
    kl_per_dim_impl(old, new, None, &[0.0; A], &[0.0; A]).total()
}

/// KL(old || new) split by action dimension (rows of the whitened representation).
pub fn kl_per_dim<const A: usize>(old: &Gaussian<A>, new: &Gaussian<A>) -> KlPerDim<A> {
    kl_per_dim_impl(old, new, None, &[0.0; A], &[0.0; A])
}

/// [`kl_per_dim`], adding `sum_j c_mean[j] d(mean_j) + c_cov[j] d(cov_j)` with respect to the
/// new distribution's `(mu, L)` into `g`. With `y = L^-1 (mu - mu_old)`, `u = L^-T (c_mean * y)`,
/// `M = L^-1 L_old` and `C = diag(c_cov)`:
/// - mean parts: `d/d mu = u`, `d/d L = -u y^T`;
/// - covariance parts: `d/d L = -L^-T C M M^T + diag(c_cov[j] / L_jj)`.
pub fn kl_per_dim_grad<const A: usize>(
    old: &Gaussian<A>,
    new: &Gaussian<A>,
    c_mean: &[f32; A],
    c_cov: &[f32; A],
    g: &mut GaussianGrad<A>,
) -> KlPerDim<A> {
    kl_per_dim_impl(old, new, Some(g), c_mean, c_cov)
}

/// [`kl_per_dim_grad`] with one coefficient for all dimensions of each part.
pub fn kl_parts_grad<const A: usize>(
    old: &Gaussian<A>,
    new: &Gaussian<A>,
    c_mean: f32,
    c_cov: f32,
    g: &mut GaussianGrad<A>,
) -> KlParts {
    kl_per_dim_impl(old, new, Some(g), &[c_mean; A], &[c_cov; A]).total()
}

/// KL(old || new) by action dimension `j`: the mean part `0.5 y_j^2` with
/// `y = L^-1 (mu - mu_old)`, and the covariance part
/// `0.5 (m_jj^2 - 1 - 2 ln m_jj + sum_{k<j} m_jk^2)` with `M = L^-1 L_old`. Each term is
/// non-negative and they sum to [`KlParts`]; for diagonal Gaussians they are the usual
/// per-dimension divergences.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KlPerDim<const A: usize> {
    /// Mean part by dimension.
    pub mean: [f32; A],
    /// Covariance part by dimension.
    pub cov: [f32; A],
}

impl<const A: usize> KlPerDim<A> {
    /// The two parts summed over dimensions.
    pub fn total(&self) -> KlParts {
        let mut t = KlParts::default();
        for j in 0..A {
            t.mean += self.mean[j];
            t.cov += self.cov[j];
        }
        t
    }
}

fn kl_per_dim_impl<const A: usize>(
    old: &Gaussian<A>,
    new: &Gaussian<A>,
    g: Option<&mut GaussianGrad<A>>,
    c_mean: &[f32; A],
    c_cov: &[f32; A],
) -> KlPerDim<A> {
    let mut d = [0f32; A];
    for j in 0..A {
        d[j] = new.mu[j] - old.mu[j];
    }
    let y = solve_lower(&new.l, &d);
    let mut out = KlPerDim {
        mean: [0.0; A],
        cov: [0.0; A],
    };
    for j in 0..A {
        out.mean[j] = 0.5 * y[j] * y[j];
    }
    // M = L^-1 L_old, lower triangular; every term below is >= 0, which keeps the tiny
    // covariance KLs of the M-step (eps_Sigma ~ 1e-4) free of cancellation.
    let m = lower_inv_times(&new.l, &old.l);
    for j in 0..A {
        let mjj = m[j][j];
        let mut r = (mjj - 1.0) * (mjj + 1.0) - 2.0 * libm::logf(mjj);
        for k in 0..j {
            r += m[j][k] * m[j][k];
        }
        out.cov[j] = 0.5 * r;
    }

    if let Some(g) = g {
        let mut cy = [0f32; A];
        for j in 0..A {
            cy[j] = c_mean[j] * y[j];
        }
        let u = solve_upper_t(&new.l, &cy);
        for j in 0..A {
            g.mu[j] += u[j];
            for k in 0..=j {
                g.l[j][k] -= u[j] * y[k];
            }
        }
        // P = L^-T C M M^T, column by column.
        for c in 0..A {
            let mut col = [0f32; A];
            for r in 0..A {
                let mut s = 0.0;
                for k in 0..=r.min(c) {
                    s += m[r][k] * m[c][k];
                }
                col[r] = c_cov[r] * s;
            }
            let p = solve_upper_t(&new.l, &col);
            for j in c..A {
                g.l[j][c] -= p[j];
            }
        }
        for j in 0..A {
            g.l[j][j] += c_cov[j] / new.l[j][j];
        }
    }
    out
}

/// Maps a gradient with respect to `(mu, L)` back to the raw head outputs.
pub fn head_backward<const A: usize, const T: usize>(
    chol_raw: &[f32; T],
    g: &GaussianGrad<A>,
    d_mean: &mut [f32; A],
    d_chol: &mut [f32; T],
) {
    const { assert!(T == A * (A + 1) / 2, "T must be A(A+1)/2") };
    *d_mean = g.mu;
    for j in 0..A {
        for k in 0..j {
            d_chol[tri_index(j, k)] = g.l[j][k];
        }
        let t = tri_index(j, j);
        d_chol[t] = g.l[j][j] * sigmoid(chol_raw[t]);
    }
}

/// Solves `L x = b` for lower-triangular `L`.
pub(crate) fn solve_lower<const A: usize>(l: &[[f32; A]; A], b: &[f32; A]) -> [f32; A] {
    let mut x = [0f32; A];
    for j in 0..A {
        let mut v = b[j];
        for k in 0..j {
            v -= l[j][k] * x[k];
        }
        x[j] = v / l[j][j];
    }
    x
}

/// Solves `L^T x = b` for lower-triangular `L`.
pub(crate) fn solve_upper_t<const A: usize>(l: &[[f32; A]; A], b: &[f32; A]) -> [f32; A] {
    let mut x = [0f32; A];
    for j in (0..A).rev() {
        let mut v = b[j];
        for k in j + 1..A {
            v -= l[k][j] * x[k];
        }
        x[j] = v / l[j][j];
    }
    x
}

/// `L^-1 B` for lower-triangular `L` and `B` (the result is lower triangular).
fn lower_inv_times<const A: usize>(l: &[[f32; A]; A], b: &[[f32; A]; A]) -> [[f32; A]; A] {
    let mut m = [[0f32; A]; A];
    for c in 0..A {
        for j in c..A {
            let mut v = b[j][c];
            for k in c..j {
                v -= l[j][k] * m[k][c];
            }
            m[j][c] = v / l[j][j];
        }
    }
    m
}
