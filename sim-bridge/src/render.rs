//! Offscreen pictures of a task with MuJoCo's own renderer (cargo feature `render`).
//!
//! The renderer keeps its own copy of the task's model, loaded with every visual asset (the
//! simulation's model leaves out the skybox, whose texture only rendering uses and which costs
//! 40-90 ms per load, see [`crate::assets`]). Each [`Renderer::render`] copies the simulation's
//! state into the renderer's own `mjData` and runs MuJoCo's kinematics there, so rendering
//! never writes to the simulated state: a rendered rollout steps exactly like an unrendered one.
//!
//! MuJoCo draws with OpenGL; mujoco-rs's `MjRenderer` gets an offscreen context from EGL,
//! which it loads at run time. On a machine without a GPU, Mesa's software rasteriser (llvmpipe)
//! serves it: Debian's packages [`DEBIAN_PACKAGES`]. Without them, [`Renderer::new`] fails with
//! [`RenderError::Unavailable`], naming the packages.
//!
//! Cameras are the model's own (`<camera name=...>` in `<domain>.xml`), plus MuJoCo's free
//! camera under the name [`FREE_CAMERA`] (dm_control's `camera_id=-1`). The default is the
//! model's first camera, camera id 0: the view the pixel-based Control Suite benchmarks use
//! (PlaNet, Dreamer, DrQ render `camera_id=0` for every domain of this crate), and the one
//! that follows the body in the walking domains (`mode="trackcom"`).

use mujoco_rs::prelude::{MjData, MjModel, MjtObjBase, MjvCamera};
use mujoco_rs::renderer::{MjRenderer, RendererError};

use crate::error::SimError;
use crate::physics::Physics;

/// The Debian packages that give MuJoCo an offscreen OpenGL context without a GPU or display
/// (EGL and Mesa's software driver).
pub const DEBIAN_PACKAGES: &str = "libegl1 libegl-mesa0 libgl1-mesa-dri libgles2";

/// The name that selects MuJoCo's free camera (looking at the model's centre).
pub const FREE_CAMERA: &str = "free";

/// The largest width or height accepted (MuJoCo allocates an offscreen buffer of that size).
pub const MAX_SIZE: u32 = 4096;

/// Why a picture could not be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// Loading the model.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// No OpenGL context could be had.
    #[error(
        "offscreen rendering is not available: {detail}. MuJoCo renders through EGL; without a \
         GPU or display, Mesa's software renderer provides it: on Debian, `apt-get install \
         {DEBIAN_PACKAGES}`"
    )]
    Unavailable {
        /// What failed, as EGL or the loader said.
        detail: String,
    },
    /// The camera name is not one of the model's.
    #[error("{domain}'s model has no camera `{camera}`; its cameras are: {}", available.join(", "))]
    UnknownCamera {
        /// The model file stem.
        domain: String,
        /// The name asked for.
        camera: String,
        /// The valid names (the model's cameras, then `free`).
        available: Vec<String>,
    },
    /// A width or height out of range.
    #[error(
        "image size {width}x{height} is out of range: each side must be 1 to {MAX_SIZE} pixels"
    )]
    Size {
        /// Width asked for.
        width: u32,
        /// Height asked for.
        height: u32,
    },
    /// MuJoCo's renderer failed after it was set up.
    #[error("rendering failed: {0}")]
    Failed(String),
}

/// An offscreen renderer for one task's model at one image size and camera.
pub struct Renderer {
    data: MjData<Box<MjModel>>,
    renderer: MjRenderer,
    domain: String,
    camera: String,
    width: u32,
    height: u32,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("domain", &self.domain)
            .field("camera", &self.camera)
            .field("width", &self.width)
            .field("height", &self.height)
            .finish_non_exhaustive()
    }
}

/// The camera names of a model, in id order.
fn model_cameras(model: &MjModel) -> Vec<String> {
    (0..model.ffi().ncam as usize)
        .map(|id| {
            model
                .id_to_name(MjtObjBase::mjOBJ_CAMERA, id)
                .map_or_else(|| id.to_string(), str::to_string)
        })
        .collect()
}

/// The cameras of `task`'s model, in id order (the first is the default), then `free`.
pub fn cameras(task: &crate::TaskDef) -> Result<Vec<String>, SimError> {
    let model = task.load_visual_model()?;
    let mut names = model_cameras(&model);
    names.push(FREE_CAMERA.into());
    Ok(names)
}

/// The MuJoCo camera for `name` (None: the model's first camera, or the free one if it has
/// none), with the name it goes by.
fn pick_camera(
    model: &MjModel,
    domain: &str,
    name: Option<&str>,
) -> Result<(MjvCamera, String), RenderError> {
    let names = model_cameras(model);
    match name {
        None if !names.is_empty() => Ok((MjvCamera::new_fixed(0), names[0].clone())),
        None => Ok((MjvCamera::new_free(model), FREE_CAMERA.into())),
        Some(n) => match names.iter().position(|c| c == n) {
            Some(id) => Ok((MjvCamera::new_fixed(id), n.into())),
            None if n == FREE_CAMERA => Ok((MjvCamera::new_free(model), n.into())),
            None => Err(RenderError::UnknownCamera {
                domain: domain.to_string(),
                camera: n.into(),
                available: names.into_iter().chain([FREE_CAMERA.into()]).collect(),
            }),
        },
    }
}

/// The error text of a renderer failure with its causes (mujoco-rs's own text is generic).
fn describe(e: &RendererError) -> String {
    let mut s = e.to_string();
    let mut source = std::error::Error::source(e);
    while let Some(cause) = source {
        s.push_str(": ");
        s.push_str(&cause.to_string());
        source = cause.source();
    }
    s
}

impl Renderer {
    /// A renderer of `task`'s model, `width` x `height` pixels, from `camera` (None: the
    /// default camera; see the module documentation).
    pub fn new(
        task: &crate::TaskDef,
        width: u32,
        height: u32,
        camera: Option<&str>,
    ) -> Result<Self, RenderError> {
        if !(1..=MAX_SIZE).contains(&width) || !(1..=MAX_SIZE).contains(&height) {
            return Err(RenderError::Size { width, height });
        }
        let domain = task.name().to_string();
        let mut model = Box::new(task.load_visual_model()?);
        // MuJoCo's offscreen buffer has the model's size (640x480 in the suite's models); a
        // larger picture needs a larger buffer, as dm_control tells its users to set in the XML.
        let global = &mut model.vis_mut().global;
        global.offwidth = global.offwidth.max(width as i32);
        global.offheight = global.offheight.max(height as i32);
        let (mjv_camera, camera) = pick_camera(&model, &domain, camera)?;
        let renderer = MjRenderer::builder()
            .width(width)
            .height(height)
            .camera(mjv_camera)
            .build(&model)
            .map_err(|e| match e {
                RendererError::GlutinError(_) => RenderError::Unavailable {
                    detail: describe(&e),
                },
                other => RenderError::Failed(describe(&other)),
            })?;
        Ok(Self {
            data: MjData::new(model),
            renderer,
            domain,
            camera,
            width,
            height,
        })
    }

    /// The camera's name.
    pub fn camera(&self) -> &str {
        &self.camera
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Draws `physics`'s current state: RGB, 3 bytes a pixel, rows from the top, `width * height
    /// * 3` bytes. `physics` must hold the same task's model.
    pub fn render(&mut self, physics: &Physics) -> Result<&[u8], RenderError> {
        let sim = physics.data();
        self.data.qpos_mut().copy_from_slice(sim.qpos());
        self.data.qvel_mut().copy_from_slice(sim.qvel());
        self.data.act_mut().copy_from_slice(sim.act());
        self.data.ctrl_mut().copy_from_slice(sim.ctrl());
        self.data.mocap_pos_mut().copy_from_slice(sim.mocap_pos());
        self.data.mocap_quat_mut().copy_from_slice(sim.mocap_quat());
        // SAFETY: `time` is a plain number that no MuJoCo invariant depends on.
        unsafe { self.data.ffi_mut().time = sim.ffi().time };
        // Body, camera, light and tendon poses: everything the scene draws.
        self.data.forward_kinematics();
        self.renderer
            .sync_data(&mut self.data)
            .map_err(|e| RenderError::Failed(describe(&e)))?;
        self.renderer
            .render()
            .map_err(|e| RenderError::Failed(describe(&e)))?;
        self.renderer
            .rgb_flat()
            .ok_or_else(|| RenderError::Failed("no RGB image".into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unavailable_names_the_debian_packages() {
        let e = RenderError::Unavailable {
            detail: "EGL was not found".into(),
        };
        let text = e.to_string();
        for p in DEBIAN_PACKAGES.split(' ') {
            assert!(text.contains(p), "{text}");
        }
        assert!(
            text.contains("EGL was not found") && text.contains("apt-get install"),
            "{text}"
        );
    }
}
