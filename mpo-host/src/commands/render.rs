//! `mpo render`.

use super::error::Error;
use crate::cli::RenderArgs;
use crate::render::{RenderOptions, RenderSummary};

/// `mpo render`: the checkpoint's mean-action policy on its evaluation episodes, as pictures.
pub fn render(args: &RenderArgs) -> Result<RenderSummary, Error> {
    let t = super::trained::trained(&args.checkpoint)?;
    let opts = RenderOptions {
        episodes: args.episodes,
        seed: args.seed.unwrap_or(t.v.meta.settings.seed),
        steps: args.steps,
        width: args.width,
        height: args.height,
        camera: args.camera.clone(),
        fps: args.fps,
        out: args.out.clone(),
        strip: args.strip.clone(),
        strip_frames: args.strip_frames,
    };
    let policy = t.policy.as_ref();
    Ok(crate::render::render(
        &t.task,
        t.v.meta.env_steps,
        &mut |o, a| policy.mean_action(o, a),
        &opts,
    )?)
}
