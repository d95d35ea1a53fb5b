//! Watching a policy: rendered rollouts of its mean action (`mpo render`) and contact sheets of
//! the evaluation policy during training (`mpo train --render-every N`).
//!
//! A rendered rollout is an evaluation: episode `i` runs on a fresh environment with the
//! evaluation seed of [`crate::eval::eval_env_seed`], observations and actions converted and
//! clipped as in [`crate::eval::evaluate_with`], and every episode runs to its end, so the
//! returns reported (and drawn on the frames) are `mpo eval`'s, bit for bit (tested). The
//! renderer only reads the simulation (sim-bridge's `render` module), so pictures change nothing.
//!
//! Frames are taken every `k`-th control step, `k = round(control rate / fps)`, and played at
//! `control rate / k` frames per second: the video runs in real time.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use sim_bridge::render::Renderer;
use sim_bridge::{Environment, SimError, TaskDef};

use crate::caption;
use crate::contact_sheet::{self, Tile};
use crate::eval::{eval_env_seed, mean_std};
use crate::video::{self, Format, MediaError, Video};

/// Why pictures could not be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// The simulator.
    #[error("simulator: {0}")]
    Sim(#[from] SimError),
    /// MuJoCo's renderer (no EGL, unknown camera, ...).
    #[error(transparent)]
    Renderer(#[from] sim_bridge::render::RenderError),
    /// Writing the video or the PNG.
    #[error(transparent)]
    Media(#[from] MediaError),
    /// A bad option.
    #[error("{0}")]
    Invalid(String),
}

/// What `mpo render` pictures and where it writes.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    /// Evaluation episodes, each on a fresh environment.
    pub episodes: u32,
    /// Evaluation seed (episode `i` uses `eval_env_seed(seed, i)`).
    pub seed: u32,
    /// Control steps pictured per episode (None: the whole episode).
    pub steps: Option<u32>,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Camera name (None: the model's first camera).
    pub camera: Option<String>,
    /// Frames per second (None: the control rate, at most 50 for a GIF).
    pub fps: Option<f64>,
    /// The video (`.gif` or `.mp4`).
    pub out: Option<PathBuf>,
    /// The contact sheet (`.png`).
    pub strip: Option<PathBuf>,
    /// Frames on the contact sheet.
    pub strip_frames: u32,
}

/// What `mpo render` prints.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderSummary {
    /// Task.
    pub task: String,
    /// Environment steps of the checkpoint.
    pub checkpoint_env_steps: u64,
    /// Evaluation seed.
    pub seed: u32,
    /// Episodes.
    pub episodes: u32,
    /// Mean return (of whole episodes, as `mpo eval`).
    pub return_mean: f64,
    /// Population standard deviation of the returns.
    pub return_std: f64,
    /// Every episode's return.
    pub returns: Vec<f64>,
    /// Control steps pictured per episode.
    pub pictured_steps: u32,
    /// A frame every this many control steps.
    pub frame_every: u32,
    /// Frames per second of the video (real time).
    pub fps: f64,
    /// Frames rendered.
    pub frames: u64,
    /// Camera.
    pub camera: String,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// The video written.
    pub out: Option<PathBuf>,
    /// The contact sheet written.
    pub strip: Option<PathBuf>,
    /// MuJoCo's rendering time per frame (scene update, draw, read-back), milliseconds.
    pub render_ms_per_frame: f64,
    /// Wall clock of the whole command after loading the checkpoint, seconds.
    pub wall_s: f64,
}

/// Where a rendered frame is in the rollout.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameInfo {
    /// Evaluation episode.
    pub episode: u32,
    /// Control steps taken in the episode (0: the initial state).
    pub step: u32,
    /// Sum of the rewards of those steps.
    pub ret: f64,
}

/// Runs evaluation episodes `0..episodes` of `seed` as [`crate::eval::evaluate_with`] does and
/// renders the state at every `(episode, step)` that `wanted` accepts, handing it to
/// `on_frame`. Every episode runs to its end. Returns the episodes' returns and the time spent
/// rendering.
#[allow(clippy::too_many_arguments)]
pub fn rollout(
    task: &TaskDef,
    seed: u32,
    episodes: u32,
    renderer: &mut Renderer,
    act_fn: &mut dyn FnMut(&[f32], &mut [f32]),
    wanted: impl Fn(u32, u32) -> bool,
    mut on_frame: impl FnMut(FrameInfo, &[u8]) -> Result<(), RenderError>,
) -> Result<(Vec<f64>, Duration), RenderError> {
    let mut returns = Vec::with_capacity(episodes as usize);
    let mut rendering = Duration::ZERO;
    let spec = task.spec();
    let (mut obs64, mut obs) = (vec![0f64; spec.obs_dim], vec![0f32; spec.obs_dim]);
    let (mut act, mut act64) = (vec![0f32; spec.act_dim], vec![0f64; spec.act_dim]);
    for episode in 0..episodes {
        let mut env = task.make(eval_env_seed(seed, episode))?;
        env.reset(&mut obs64);
        let (mut ret, mut step, mut done) = (0.0, 0u32, false);
        loop {
            if wanted(episode, step) {
                let t = Instant::now();
                let rgb = renderer.render(env.physics())?;
                rendering += t.elapsed();
                on_frame(FrameInfo { episode, step, ret }, rgb)?;
            }
            if done {
                break;
            }
            for (o, x) in obs.iter_mut().zip(&obs64) {
                *o = *x as f32;
            }
            act_fn(&obs, &mut act);
            for (o, a) in act64.iter_mut().zip(&act) {
                *o = a.clamp(-1.0, 1.0) as f64;
            }
            let s = env.try_step(&act64, &mut obs64)?;
            ret += s.reward;
            step += 1;
            done = s.last;
        }
        returns.push(ret);
    }
    Ok((returns, rendering))
}

/// `n` indices spread evenly over `0..count`, first and last included.
fn evenly(count: u64, n: u32) -> Vec<u64> {
    let n = (n as u64).min(count);
    match n {
        0 => Vec::new(),
        1 => vec![0],
        _ => (0..n)
            .map(|j| ((j as f64 * (count - 1) as f64) / (n - 1) as f64).round() as u64)
            .collect(),
    }
}

/// The caption of a frame or tile.
fn label(f: &FrameInfo, episodes: u32) -> String {
    let ep = if episodes > 1 {
        format!("ep {}  ", f.episode)
    } else {
        String::new()
    };
    format!("{ep}step {}  return {:.1}", f.step, f.ret)
}

/// Frame timing for a task: `(frame_every, fps)` from the requested rate (None: the control
/// rate, capped at what a GIF plays when the video is one).
fn timing(
    control_timestep: f64,
    fps: Option<f64>,
    format: Option<Format>,
) -> Result<(u32, f64), RenderError> {
    let rate = 1.0 / control_timestep;
    let wanted = match fps {
        Some(f) if f.is_finite() && f > 0.0 => f,
        Some(f) => return Err(RenderError::Invalid(format!("--fps {f} must be positive"))),
        None if format == Some(Format::Mp4) => rate,
        None => rate.min(video::GIF_MAX_FPS),
    };
    let every = ((rate / wanted).round() as u32).max(1);
    Ok((every, rate / every as f64))
}

/// The request's checks, before anything is simulated: something to write, at least one
/// episode and step, file names whose format is known. Returns the video's format.
fn check_request(opts: &RenderOptions) -> Result<Option<Format>, RenderError> {
    if opts.out.is_none() && opts.strip.is_none() {
        return Err(RenderError::Invalid(
            "nothing to write: give --out and/or --strip".into(),
        ));
    }
    if opts.episodes == 0 || opts.steps == Some(0) {
        return Err(RenderError::Invalid(
            "--episodes and --steps must be at least 1".into(),
        ));
    }
    let format = opts.out.as_deref().map(Format::of).transpose()?;
    if let Some(p) = &opts.strip {
        contact_sheet::check_path(p)?;
    }
    Ok(format)
}

/// A contact sheet of `tiles` (each `w` x `h`) under `title`, written as a PNG.
fn write_sheet(
    path: &Path,
    title: &str,
    tiles: &[Tile],
    w: usize,
    h: usize,
) -> Result<(), RenderError> {
    let (sheet, sw, sh) = contact_sheet::compose(title, tiles, w, h);
    contact_sheet::write_png(path, &sheet, sw, sh)?;
    Ok(())
}

/// Which steps are pictured: every `every`-th up to `pictured` in the video, and
/// `strip_frames` of those spread evenly over all episodes on the contact sheet.
struct Pick {
    pictured: u32,
    every: u32,
    per_episode: u64,
    strip_at: Option<Vec<u64>>,
}

impl Pick {
    fn new(pictured: u32, every: u32, opts: &RenderOptions) -> Self {
        let per_episode = (pictured / every) as u64 + 1;
        let slots = opts.episodes as u64 * per_episode;
        Self {
            pictured,
            every,
            per_episode,
            strip_at: opts
                .strip
                .as_ref()
                .map(|_| evenly(slots, opts.strip_frames)),
        }
    }

    fn on_video(&self, step: u32) -> bool {
        step <= self.pictured && step.is_multiple_of(self.every)
    }

    fn in_strip(&self, episode: u32, step: u32) -> bool {
        let slot = episode as u64 * self.per_episode + (step / self.every) as u64;
        self.on_video(step)
            && self
                .strip_at
                .as_ref()
                .is_some_and(|at| at.binary_search(&slot).is_ok())
    }
}

/// `mpo render` for a loaded policy: the video and/or the contact sheet of `opts`. Its length
/// is the frame sink (caption, video, tiles) and the summary's field list.
// Long for its summary's field list (a third of it) and the frame callback, which must see
// the video, the strip and the caption at once; the steps it calls are each their own
// function (`check_request`, `timing`, `rollout`, `write_sheet`).
pub fn render(
    task: &TaskDef,
    checkpoint_env_steps: u64,
    act_fn: &mut dyn FnMut(&[f32], &mut [f32]),
    opts: &RenderOptions,
) -> Result<RenderSummary, RenderError> {
    let started = Instant::now();
    let format = check_request(opts)?;
    let spec = task.spec();
    let pictured = opts.steps.map_or(spec.episode_steps as u32, |s| {
        s.min(spec.episode_steps as u32)
    });
    let (every, fps) = timing(spec.control_timestep, opts.fps, format)?;
    let mut renderer = Renderer::new(task, opts.width, opts.height, opts.camera.as_deref())?;
    let (w, h) = (opts.width as usize, opts.height as usize);
    let mut video = match &opts.out {
        Some(p) => Some(Video::create(p, opts.width, opts.height, fps)?),
        None => None,
    };
    let pick = Pick::new(pictured, every, opts);
    let has_video = video.is_some();
    let (scale, mut frame, mut tiles, mut frames) =
        (caption::scale_for(h), Vec::new(), Vec::new(), 0u64);
    let (returns, rendering) = rollout(
        task,
        opts.seed,
        opts.episodes,
        &mut renderer,
        act_fn,
        |e, s| (has_video && pick.on_video(s)) || pick.in_strip(e, s),
        |info, rgb| {
            frames += 1;
            let text = label(&info, opts.episodes);
            if pick.in_strip(info.episode, info.step) {
                tiles.push(Tile {
                    rgb: rgb.to_vec(),
                    label: text.clone(),
                });
            }
            if let Some(v) = video.as_mut() {
                frame.clear();
                frame.extend_from_slice(rgb);
                caption::draw(&mut frame, w, h, 2, 2, scale, &text);
                v.push(&frame)?;
            }
            Ok(())
        },
    )?;
    if let Some(v) = video {
        v.finish()?;
    }
    let (return_mean, return_std) = mean_std(&returns);
    if let Some(p) = &opts.strip {
        let title = format!(
            "{}  checkpoint step {checkpoint_env_steps}  eval seed {}  return {}",
            task.name(),
            opts.seed,
            returns
                .iter()
                .map(|r| format!("{r:.1}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
        write_sheet(p, &title, &tiles, w, h)?;
    }
    Ok(RenderSummary {
        task: task.name().into(),
        checkpoint_env_steps,
        seed: opts.seed,
        episodes: opts.episodes,
        return_mean,
        return_std,
        returns,
        pictured_steps: pictured,
        frame_every: every,
        fps,
        frames,
        camera: renderer.camera().into(),
        width: opts.width,
        height: opts.height,
        out: opts.out.clone(),
        strip: opts.strip.clone(),
        render_ms_per_frame: rendering.as_secs_f64() * 1e3 / frames.max(1) as f64,
        wall_s: started.elapsed().as_secs_f64(),
    })
}

/// `mpo train --render-every N`: after every `every`-th evaluation (the untrained policy's
/// first), a contact sheet of evaluation episode 0 of the policy just evaluated, in
/// `<run>/renders/step-<env steps>.png`.
#[derive(Clone, Debug)]
pub struct EvaluationStrips {
    /// Every this many evaluations.
    pub every: u32,
    /// Tiles per sheet, evenly over the episode.
    pub frames: u32,
    /// Tile width.
    pub width: u32,
    /// Tile height.
    pub height: u32,
}

impl EvaluationStrips {
    /// Sheets every `every` evaluations at the default size (8 tiles of 320x240).
    pub fn new(every: u32) -> Result<Self, RenderError> {
        if every == 0 {
            return Err(RenderError::Invalid(
                "--render-every must be at least 1".into(),
            ));
        }
        Ok(Self {
            every,
            frames: 8,
            width: 320,
            height: 240,
        })
    }

    /// Opens a renderer for `task` once, so that a machine that cannot render says so before
    /// training starts rather than at the first sheet.
    pub fn check(&self, task: &TaskDef) -> Result<(), RenderError> {
        Renderer::new(task, self.width, self.height, None)?;
        Ok(())
    }

    /// After evaluation number `index` (0: the untrained policy) at `env_steps`: the sheet, if
    /// this evaluation is one of every `every`. Returns the file written.
    #[allow(clippy::too_many_arguments)]
    pub fn after_evaluation(
        &self,
        index: usize,
        env_steps: u64,
        task: &TaskDef,
        seed: u32,
        run_dir: &Path,
        act_fn: &mut dyn FnMut(&[f32], &mut [f32]),
    ) -> Result<Option<PathBuf>, RenderError> {
        if !index.is_multiple_of(self.every as usize) {
            return Ok(None);
        }
        let episode_steps = task.spec().episode_steps as u64;
        let at = evenly(episode_steps + 1, self.frames);
        let mut renderer = Renderer::new(task, self.width, self.height, None)?;
        let mut tiles = Vec::new();
        let (returns, _) = rollout(
            task,
            seed,
            1,
            &mut renderer,
            act_fn,
            |_, s| at.binary_search(&(s as u64)).is_ok(),
            |info, rgb| {
                tiles.push(Tile {
                    rgb: rgb.to_vec(),
                    label: label(&info, 1),
                });
                Ok(())
            },
        )?;
        let dir = run_dir.join("renders");
        std::fs::create_dir_all(&dir).map_err(|e| MediaError::Write {
            path: dir.clone(),
            message: e.to_string(),
        })?;
        let path = dir.join(format!("step-{env_steps:09}.png"));
        let title = format!(
            "{}  step {env_steps}  eval episode 0  return {:.1}",
            task.name(),
            returns[0]
        );
        write_sheet(
            &path,
            &title,
            &tiles,
            self.width as usize,
            self.height as usize,
        )?;
        Ok(Some(path))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evenly_spread_indices() {
        assert_eq!(evenly(1001, 5), vec![0, 250, 500, 750, 1000]);
        assert_eq!(evenly(3, 8), vec![0, 1, 2]);
        assert_eq!(evenly(10, 1), vec![0]);
        assert!(evenly(10, 0).is_empty());
    }

    #[test]
    fn frame_timing_plays_in_real_time() {
        // cartpole: 100 Hz control; a GIF at most 50 fps: every 2nd step at 50 fps.
        assert_eq!(timing(0.01, None, Some(Format::Gif)).unwrap(), (2, 50.0));
        assert_eq!(timing(0.01, None, Some(Format::Mp4)).unwrap(), (1, 100.0));
        // walker: 40 Hz.
        assert_eq!(timing(0.025, None, None).unwrap(), (1, 40.0));
        // 30 fps asked at 100 Hz: every 3rd step, played at 33.3 fps.
        let (k, f) = timing(0.01, Some(30.0), None).unwrap();
        assert_eq!(k, 3);
        assert!((f - 100.0 / 3.0).abs() < 1e-9);
        assert!(timing(0.01, Some(0.0), None).is_err());
    }
}
