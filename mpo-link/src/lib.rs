//! `mpo-link`: the iceoryx2 link between the plant (the host stepping MuJoCo) and the
//! controller process (mpo-core inference, as it would run on the robot).
//!
//! - [`messages`]: the fixed-size `#[repr(C)]` messages and their validation;
//! - [`service`]: run identity (unique service names and file prefix), the ports of each side;
//! - [`plant`]: the host endpoint ([`plant::Plant`]): request an action with a deadline, push
//!   parameters;
//! - [`external`]: a plant in another process (a Gymnasium environment, a robot's software):
//!   the protocol and the learner's end ([`external::ExternalPlant`]);
//! - [`controller`]: the controller loop behind the `mpo-controller` binary;
//! - [`realtime`]: `SCHED_FIFO` and timer slack for paced loops.
//!
//! Both sides wait either event-driven (an event service per direction, a notify after each
//! send) or by busy-polling ([`service::WaitMode`]).

pub mod controller;
pub mod external;
pub mod fleet;
pub mod messages;
pub mod plant;
pub mod realtime;
pub mod service;

pub use messages::{MAX_ACT, MAX_OBS};
pub use plant::{Action, Miss, Plant, PlantConfig, PlantStats};
pub use service::{LinkError, RunId, WaitMode};
