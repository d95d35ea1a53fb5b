//! The trunk the residual policy and critic share: the blocks and the final normalisation
//! after each network's embedding (the maths in the parent module's doc).

use bytemuck::Zeroable;

#[cfg(feature = "train")]
use crate::hypersphere::normalize_columns;
use crate::layer_norm::LayerNorm;
use crate::linear::{Linear, accumulate};
#[cfg(feature = "train")]
use crate::linear::{bias_grad_chunks, relu_backward, transpose, weight_grad_chunks};
#[cfg(feature = "train")]
use crate::network::{block_rows, chunk_slices};
use crate::rng::Rng;

/// One pre-LayerNorm residual block: `x + down(relu(up(norm(x))))`.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct Block<const W: usize, const F: usize> {
    /// The block's input normalisation.
    pub norm: LayerNorm<W>,
    /// Into the inner width.
    pub up: Linear<W, F>,
    /// Back to the width, added to the input.
    pub down: Linear<F, W>,
}

crate::impl_params_for_fields!(Block<const W: usize, const F: usize> {
    norm: LayerNorm<W>,
    up: Linear<W, F>,
    down: Linear<F, W>,
});

/// `D` residual blocks and the final normalisation: what comes after a network's embedding.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct Trunk<const W: usize, const F: usize, const D: usize> {
    /// The blocks, in order.
    pub blocks: [Block<W, F>; D],
    /// The final normalisation (the heads read its output).
    pub norm: LayerNorm<W>,
}

crate::impl_params_for_fields!(Trunk<const W: usize, const F: usize, const D: usize> {
    blocks: [Block<W, F>; D],
    norm: LayerNorm<W>,
});

/// A batch's activations through a [`Trunk`] and its backward scratch: `B` rows.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct TrunkTape<const B: usize, const W: usize, const F: usize, const D: usize> {
    /// The residual stream: the embedding on entry to [`Trunk::forward`], `x_D` after it.
    pub stream: [[f32; W]; B],
    /// Each block's normalised input.
    pub xhat: [[[f32; W]; B]; D],
    /// Each block's `1 / sqrt(var + EPS)` per row.
    pub rstd: [[f32; B]; D],
    /// Each block's normalised input after gain and bias (the input of `up`).
    pub y: [[[f32; W]; B]; D],
    /// Each block's inner activations (after the ReLU).
    pub h: [[[f32; F]; B]; D],
    /// The final normalisation's normalised input.
    pub fxhat: [[f32; W]; B],
    /// The final normalisation's `1 / sqrt(var + EPS)` per row.
    pub frstd: [f32; B],
    /// The trunk's output (the heads' input).
    pub z: [[f32; W]; B],
    /// The gradient at `z` (filled by the network's heads before [`Trunk::backprop`]).
    pub d_z: [[f32; W]; B],
    /// The gradient at each block's output `x_(d+1)`.
    pub d_out: [[[f32; W]; B]; D],
    /// The gradient at each block's inner pre-activations.
    pub d_h: [[[f32; F]; B]; D],
    /// The gradient at each block's normalisation output.
    pub d_y: [[[f32; W]; B]; D],
    /// The gradient at the embedding's output `x_0`.
    pub d_x0: [[f32; W]; B],
}

#[cfg(feature = "train")]
/// A trunk's weights transposed, as [`Trunk::backprop`] multiplies by them.
#[derive(Clone, Zeroable)]
#[repr(C)]
pub struct TrunkTransposed<const W: usize, const F: usize, const D: usize> {
    /// Each block's `up` transposed.
    pub up: [[[f32; W]; F]; D],
    /// Each block's `down` transposed.
    pub down: [[[f32; F]; W]; D],
}

impl<const W: usize, const F: usize, const D: usize> Trunk<W, F, D> {
    /// Identity normalisations, uniform fan-in layers.
    pub fn init(&mut self, rng: &mut Rng) {
        for b in self.blocks.iter_mut() {
            b.norm.init();
            b.up.init_uniform(rng);
            b.down.init_uniform(rng);
        }
        self.norm.init();
    }

    #[cfg(feature = "train")]
    /// Every block's `up` and `down` onto the unit sphere ([`crate::hypersphere`]).
    pub fn project_weights(&mut self) {
        for b in self.blocks.iter_mut() {
            normalize_columns(&mut [&mut b.up.w[..]]);
            normalize_columns(&mut [&mut b.down.w[..]]);
        }
    }

    /// The blocks and the final normalisation on `tape.stream` (the embedding of each row),
    /// into `tape.z`.
    pub fn forward<const B: usize>(&self, tape: &mut TrunkTape<B, W, F, D>) {
        for (d, b) in self.blocks.iter().enumerate() {
            let t = &mut *tape;
            b.norm
                .forward_rows(&t.stream, &mut t.xhat[d], &mut t.rstd[d], &mut t.y[d]);
            b.up.forward_relu(&t.y[d], &mut t.h[d]);
            add_bias(&mut t.stream, &b.down.b);
            accumulate(&t.h[d], &b.down.w, &mut t.stream);
        }
        let t = &mut *tape;
        self.norm
            .forward_rows(&t.stream, &mut t.fxhat, &mut t.frstd, &mut t.z);
    }

    /// [`Self::forward`] for one row without a tape (the inference path; the same bits):
    /// `x` is the embedding on entry (changed), `z` the output.
    pub fn forward_one(&self, x: &mut [f32; W], z: &mut [f32; W]) {
        let mut xhat = [0f32; W];
        let mut y = [[0f32; W]; 1];
        let mut h = [[0f32; F]; 1];
        let x = core::slice::from_mut(x);
        for b in &self.blocks {
            b.norm.normalize(&x[0], &mut xhat, &mut y[0]);
            b.up.forward_relu(&y, &mut h);
            add_bias(x, &b.down.b);
            accumulate(&h, &b.down.w, x);
        }
        self.norm.normalize(&x[0], &mut xhat, z);
    }

    #[cfg(feature = "train")]
    /// Fills `t` for [`Self::backprop`].
    pub fn transpose_into(&self, t: &mut TrunkTransposed<W, F, D>) {
        for (d, b) in self.blocks.iter().enumerate() {
            transpose(&b.up.w, &mut t.up[d]);
            transpose(&b.down.w, &mut t.down[d]);
        }
    }

    #[cfg(feature = "train")]
    /// Carries `tape.d_z` (the gradient at the output) back through the final norm and the
    /// blocks to `tape.d_x0`, keeping what the weight gradients need (module doc).
    pub fn backprop<const B: usize>(
        &self,
        tape: &mut TrunkTape<B, W, F, D>,
        t: &TrunkTransposed<W, F, D>,
    ) {
        let tp = &mut *tape;
        for row in tp.d_x0.iter_mut() {
            row.fill(0.0);
        }
        self.norm
            .backward_rows(&tp.fxhat, &tp.frstd, &tp.d_z, &mut tp.d_x0);
        for (d, b) in self.blocks.iter().enumerate().rev() {
            tp.d_out[d] = tp.d_x0;
            for row in tp.d_h[d].iter_mut() {
                row.fill(0.0);
            }
            accumulate(&tp.d_out[d], &t.down[d], &mut tp.d_h[d]);
            relu_backward(&tp.h[d], &mut tp.d_h[d]);
            for row in tp.d_y[d].iter_mut() {
                row.fill(0.0);
            }
            accumulate(&tp.d_h[d], &t.up[d], &mut tp.d_y[d]);
            b.norm
                .backward_rows(&tp.xhat[d], &tp.rstd[d], &tp.d_y[d], &mut tp.d_x0);
        }
    }

    #[cfg(feature = "train")]
    /// Splits `self` (a gradient) into independent blocks for [`TrunkPart::compute`]: per
    /// block its norm, `up`'s weights by rows, `up`'s bias, `down`'s weights by rows, `down`'s
    /// bias; then the final norm. The blocks depend only on the sizes.
    pub fn push_parts<'a, const MAX: usize, P>(
        &'a mut self,
        parts: &mut heapless::Vec<P, MAX>,
        wrap: impl Fn(TrunkPart<'a, W, F>) -> P,
    ) {
        let mut push = |p: TrunkPart<'a, W, F>| {
            if parts.push(wrap(p)).is_err() {
                panic!("more than {MAX} gradient blocks");
            }
        };
        let Trunk { blocks, norm } = self;
        for (d, b) in blocks.iter_mut().enumerate() {
            push(TrunkPart::Norm { d, ln: &mut b.norm });
            let mut i0 = 0;
            for w in b.up.w.chunks_mut(block_rows(W)) {
                let n = w.len();
                push(TrunkPart::Up { d, w, i0 });
                i0 += n;
            }
            push(TrunkPart::UpBias { d, b: &mut b.up.b });
            let mut i0 = 0;
            for w in b.down.w.chunks_mut(block_rows(F)) {
                let n = w.len();
                push(TrunkPart::Down { d, w, i0 });
                i0 += n;
            }
            push(TrunkPart::DownBias {
                d,
                b: &mut b.down.b,
            });
        }
        push(TrunkPart::Norm { d: D, ln: norm });
    }
}

/// `rows[n][o] += b[o]`.
fn add_bias<const W: usize>(rows: &mut [[f32; W]], b: &[f32; W]) {
    for row in rows.iter_mut() {
        for o in 0..W {
            row[o] += b[o];
        }
    }
}

#[cfg(feature = "train")]
/// One independent block of a trunk's weight gradient (see [`Trunk::push_parts`]).
pub enum TrunkPart<'a, const W: usize, const F: usize> {
    /// Block `d`'s normalisation, or the final one when `d` is the block count.
    Norm {
        /// The block.
        d: usize,
        /// Gain and bias.
        ln: &'a mut LayerNorm<W>,
    },
    /// Rows `i0 ..` of block `d`'s `up` weights.
    Up {
        /// The block.
        d: usize,
        /// The rows.
        w: &'a mut [[f32; F]],
        /// Index of the first row.
        i0: usize,
    },
    /// Block `d`'s `up` bias.
    UpBias {
        /// The block.
        d: usize,
        /// The bias.
        b: &'a mut [f32; F],
    },
    /// Rows `i0 ..` of block `d`'s `down` weights.
    Down {
        /// The block.
        d: usize,
        /// The rows.
        w: &'a mut [[f32; W]],
        /// Index of the first row.
        i0: usize,
    },
    /// Block `d`'s `down` bias.
    DownBias {
        /// The block.
        d: usize,
        /// The bias.
        b: &'a mut [f32; W],
    },
}

#[cfg(feature = "train")]
impl<const W: usize, const F: usize> TrunkPart<'_, W, F> {
    /// Computes this block of the gradient from every chunk's tape (chunks in order, rows
    /// ascending; overwriting it) and returns the sum of its squares.
    pub fn compute<const B: usize, const D: usize>(
        &mut self,
        tapes: &[&TrunkTape<B, W, F, D>],
    ) -> f64 {
        use crate::actor::sum_squares;
        use crate::layer_norm::param_grad_chunks;
        match self {
            Self::Norm { d, ln } => {
                let d = *d;
                if d == D {
                    let xhat = chunk_slices(tapes, |t| &t.fxhat[..]);
                    let d_z = chunk_slices(tapes, |t| &t.d_z[..]);
                    param_grad_chunks(&xhat, &d_z, ln);
                } else {
                    let xhat = chunk_slices(tapes, |t| &t.xhat[d][..]);
                    let d_y = chunk_slices(tapes, |t| &t.d_y[d][..]);
                    param_grad_chunks(&xhat, &d_y, ln);
                }
                sum_squares(&ln.g) + sum_squares(&ln.b)
            }
            Self::Up { d, w, i0 } => {
                let d = *d;
                let y = chunk_slices(tapes, |t| &t.y[d][..]);
                let d_h = chunk_slices(tapes, |t| &t.d_h[d][..]);
                weight_grad_chunks(&y, &d_h, *i0, w);
                sum_squares(w.as_flattened())
            }
            Self::UpBias { d, b } => {
                let d = *d;
                bias_grad_chunks(&chunk_slices(tapes, |t| &t.d_h[d][..]), b);
                sum_squares(&b[..])
            }
            Self::Down { d, w, i0 } => {
                let d = *d;
                let h = chunk_slices(tapes, |t| &t.h[d][..]);
                let g = chunk_slices(tapes, |t| &t.d_out[d][..]);
                weight_grad_chunks(&h, &g, *i0, w);
                sum_squares(w.as_flattened())
            }
            Self::DownBias { d, b } => {
                let d = *d;
                bias_grad_chunks(&chunk_slices(tapes, |t| &t.d_out[d][..]), b);
                sum_squares(&b[..])
            }
        }
    }
}

/// Most gradient blocks a residual network splits into (depth up to about 6).
pub const MAX_PARTS: usize = 160;
