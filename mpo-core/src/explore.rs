//! Exploration: the collector's random stream and the noise of the behaviour policy, apart
//! from any learner.
//!
//! The in-process trainer keeps one [`Explorer`] inside its [`crate::agent::Agent`]; a plant
//! of a fleet (a process stepping its own environment and sending transitions to a learner
//! elsewhere) keeps its own, with the same code, so a one-plant fleet draws exactly the
//! warm-up actions and noise of the in-process run. Plain data (`Zeroable`, no pointers):
//! created zeroed in place, then [`Explorer::init`].

use bytemuck::Zeroable;

use crate::rng::Rng;

/// Rows of the pink noise generator: its spectrum is `1/f` out to `2^10 = 1024` steps, past
/// a Control Suite episode's 1000.
pub const PINK_OCTAVES: usize = 10;

/// How the exploration noise runs in time (see `AgentSchedule::noise_corr` and
/// `AgentSchedule::noise_pink` for why).
#[derive(Clone, Copy, Debug, PartialEq, Zeroable)]
pub struct NoiseKind {
    /// Lag-one correlation `beta` in `[0, 1)` of an AR(1) noise; 0 = independent draws.
    pub corr: f32,
    /// Voss's pink generator instead (exclusive with `corr > 0`).
    pub pink: bool,
}

/// The collector's stream and the state of the exploration noise of one environment.
#[derive(Clone, Zeroable)]
pub struct Explorer<const ACT: usize> {
    /// State of the collector's stream (warm-up actions and exploration noise).
    pub collector: [u8; 32],
    /// The noise's kind.
    pub kind: NoiseKind,
    /// The last standard-normal exploration draw of this episode (for correlated noise).
    pub noise: [f32; ACT],
    /// True once [`Explorer::noise`] holds a draw of the current episode.
    pub noise_live: bool,
    /// The pink noise generator's rows (row `k` redrawn every `2^k` steps of an episode).
    pub pink: [[f32; ACT]; PINK_OCTAVES],
    /// Draws made this episode by the pink noise generator (its clock).
    pub pink_step: u32,
}

impl<const ACT: usize> Explorer<ACT> {
    /// Starts from the collector stream state `collector`, between episodes.
    pub fn init(&mut self, collector: [u8; 32], kind: NoiseKind) {
        self.collector = collector;
        self.kind = kind;
        self.noise = [0.0; ACT];
        self.noise_live = false;
        self.pink = [[0.0; ACT]; PINK_OCTAVES];
        self.pink_step = 0;
    }

    /// A uniformly random action in `[-1, 1]` (the warm-up's) and its log-density.
    pub fn uniform_action(&mut self, action: &mut [f32; ACT]) -> f32 {
        let mut rng = Rng::from_state(self.collector);
        for a in action.iter_mut() {
            *a = rng.uniform_range(-1.0, 1.0);
        }
        self.collector = rng.state();
        -(ACT as f32) * core::f32::consts::LN_2
    }

    /// The standard-normal draws `z` a policy turns into its sample `mu + L z`: independent
    /// draws from the collector's stream, with `corr > 0` their AR(1) combination with the
    /// episode's previous draw, or with `pink` the pink generator's next value.
    pub fn draw_noise(&mut self, z: &mut [f32; ACT]) {
        let mut rng = Rng::from_state(self.collector);
        if self.kind.pink {
            self.draw_pink(&mut rng, z);
            self.collector = rng.state();
            return;
        }
        rng.fill_normal(z);
        self.collector = rng.state();
        let beta = self.kind.corr;
        if beta > 0.0 {
            if self.noise_live {
                let fresh = libm::sqrtf(1.0 - beta * beta);
                for (x, p) in z.iter_mut().zip(&self.noise) {
                    *x = beta * p + fresh * *x;
                }
            }
            self.noise = *z;
            self.noise_live = true;
        }
    }

    /// Voss's pink generator: at the episode's step `t`, row `k` is redrawn when `2^k`
    /// divides `t` (all rows at `t = 0`, row 0 at every step), and `z` is the rows' sum over
    /// `sqrt(PINK_OCTAVES)`.
    fn draw_pink(&mut self, rng: &mut Rng, z: &mut [f32; ACT]) {
        if !self.noise_live {
            self.pink_step = 0;
            self.noise_live = true;
        }
        let t = self.pink_step;
        for (k, row) in self.pink.iter_mut().enumerate() {
            if t & ((1u32 << k) - 1) == 0 {
                rng.fill_normal(row);
            }
        }
        self.pink_step = t.wrapping_add(1);
        let scale = 1.0 / libm::sqrtf(PINK_OCTAVES as f32);
        for (i, x) in z.iter_mut().enumerate() {
            let sum: f32 = self.pink.iter().map(|row| row[i]).sum();
            *x = sum * scale;
        }
    }

    /// Marks the start of an episode: correlated and pink noise restart.
    pub fn begin_episode(&mut self) {
        self.noise_live = false;
    }
}
