//! The fleet over iceoryx2, between processes of one host: two publish-subscribe services of
//! byte slices and an event service per direction, all named `mpo/<run>/fleet/...` under the
//! run's file prefix (so a run's files are found by its id, and only its user may read or
//! write them: iceoryx2 creates them owner-only).
//!
//! - `fleet/up`: every plant publishes, the learner subscribes. Each connection buffers
//!   [`UP_BUFFER`] frames and drops the oldest when full (the learner drains it between
//!   updates; a free-running plant is never held up by it).
//! - `fleet/down`: the learner publishes parameters, rounds and answers, every plant
//!   subscribes; a buffer of [`DOWN_BUFFER`] frames holds a whole parameter generation.
//! - events `fleet/to-learner` and `fleet/to-plants`: a notify after each send, so both sides
//!   sleep in `ppoll` instead of spinning.
//!
//! Either side may start first (`open_or_create` with identical settings), and a plant that
//! starts before the learner simply waits.

use core::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use super::frames::{MAX_DOWN, block_len};
use super::{LearnerPort, PlantPort};
use crate::service::{LinkError, RunId, err, wait_for_event};

/// Most plants of one host on iceoryx2 (each is a publisher of `up` and a subscriber of
/// `down`; the services' shared memory is sized for this many).
pub const MAX_LOCAL: usize = 16;
/// Frames each plant's connection to the learner buffers.
pub const UP_BUFFER: usize = 16;
/// Frames each plant buffers from the learner: a whole parameter generation (at most 32
/// blocks) and the frames around it.
pub const DOWN_BUFFER: usize = 40;

type Svc = ipc::Service;
type Factory = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Svc, [u8], ()>;

fn service_name(run: &RunId, leaf: &str) -> Result<ServiceName, LinkError> {
    ServiceName::new(&format!("mpo/{}/fleet/{leaf}", run.as_str())).map_err(err("service name"))
}

fn node(run: &RunId, name: &str) -> Result<Node<Svc>, LinkError> {
    iceoryx2::prelude::set_log_level_from_env_or(LogLevel::Error);
    let cfg = run.config()?;
    NodeBuilder::new()
        .config(&cfg)
        .name(&NodeName::new(name).map_err(err("node name"))?)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Svc>()
        .map_err(err("node"))
}

fn bytes_service(
    node: &Node<Svc>,
    run: &RunId,
    leaf: &str,
    up: bool,
) -> Result<Factory, LinkError> {
    let what = format!("the fleet's {leaf} service");
    let (publishers, subscribers, buffer) = match up {
        true => (MAX_LOCAL + 2, 2, UP_BUFFER),
        false => (2, MAX_LOCAL + 2, DOWN_BUFFER),
    };
    node.service_builder(&service_name(run, leaf)?)
        .publish_subscribe::<[u8]>()
        .enable_safe_overflow(true)
        .subscriber_max_buffer_size(buffer)
        .history_size(0)
        .max_publishers(publishers)
        .max_subscribers(subscribers)
        .max_nodes(MAX_LOCAL + 4)
        .open_or_create()
        .map_err(err(&what))
}

fn event(
    node: &Node<Svc>,
    run: &RunId,
    leaf: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<Svc>, LinkError> {
    node.service_builder(&service_name(run, leaf)?)
        .event()
        .max_notifiers(MAX_LOCAL + 4)
        .max_listeners(MAX_LOCAL + 4)
        .max_nodes(MAX_LOCAL + 4)
        .open_or_create()
        .map_err(err("fleet event service"))
}

fn send(publisher: &Publisher<Svc, [u8], ()>, frame: &[u8]) -> Result<(), LinkError> {
    let sample = publisher
        .loan_slice_uninit(frame.len())
        .map_err(err("loan a frame"))?;
    sample
        .write_from_slice(frame)
        .send()
        .map_err(err("send a frame"))?;
    Ok(())
}

fn drain(sub: &Subscriber<Svc, [u8], ()>, f: &mut dyn FnMut(&[u8])) -> Result<usize, LinkError> {
    let mut n = 0;
    while let Some(sample) = sub.receive().map_err(err("receive a frame"))? {
        f(sample.payload());
        n += 1;
    }
    Ok(n)
}

/// The learner's end over iceoryx2.
pub struct IpcLearner {
    ports: Option<LearnerPorts>,
    run: RunId,
}

struct LearnerPorts {
    down: Publisher<Svc, [u8], ()>,
    up: Subscriber<Svc, [u8], ()>,
    notify: Notifier<Svc>,
    listen: Listener<Svc>,
    node: Node<Svc>,
}

impl IpcLearner {
    /// Opens the learner's side of `run` (after clearing what a killed learner of the same
    /// run left registered).
    pub fn open(run: &RunId) -> Result<Self, LinkError> {
        let node = node(run, "mpo-learner")?;
        let _ = node.try_cleanup_dead_nodes();
        let down = bytes_service(&node, run, "down", false)?
            .publisher_builder()
            .initial_max_slice_len(MAX_DOWN)
            .max_loaned_samples(2)
            .create()
            .map_err(err("fleet down publisher"))?;
        let up = bytes_service(&node, run, "up", true)?
            .subscriber_builder()
            .create()
            .map_err(err("fleet up subscriber"))?;
        let notify = event(&node, run, "to-plants")?
            .notifier_builder()
            .create()
            .map_err(err("fleet notifier"))?;
        let listen = event(&node, run, "to-learner")?
            .listener_builder()
            .create()
            .map_err(err("fleet listener"))?;
        run.restrict_files();
        Ok(Self {
            ports: Some(LearnerPorts {
                down,
                up,
                notify,
                listen,
                node,
            }),
            run: run.clone(),
        })
    }

    fn ports(&self) -> &LearnerPorts {
        self.ports.as_ref().expect("open until dropped")
    }

    /// The run.
    pub fn run(&self) -> &RunId {
        &self.run
    }
}

impl LearnerPort for IpcLearner {
    fn send_down(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        send(&self.ports().down, frame)?;
        let _ = self.ports().notify.notify();
        Ok(())
    }
    fn recv_up(&mut self, f: &mut dyn FnMut(&[u8])) -> Result<usize, LinkError> {
        drain(&self.ports().up, f)
    }
    fn wait(&mut self, timeout: Duration) {
        wait_for_event(&self.ports().listen, timeout);
    }
    fn cleanup_dead(&mut self) {
        let _ = self.ports().node.try_cleanup_dead_nodes();
    }
    fn name(&self) -> &'static str {
        "iceoryx2"
    }
}

impl Drop for IpcLearner {
    fn drop(&mut self) {
        if let Some(p) = &self.ports {
            let _ = p.node.try_cleanup_dead_nodes();
        }
        self.ports = None;
        self.run.remove_if_last();
    }
}

/// A plant's end over iceoryx2.
pub struct IpcPlant {
    up: Option<Publisher<Svc, [u8], ()>>,
    down: Option<Subscriber<Svc, [u8], ()>>,
    notify: Option<Notifier<Svc>>,
    listen: Option<Listener<Svc>>,
    node: Option<Node<Svc>>,
    run: RunId,
}

impl IpcPlant {
    /// Opens a plant's side of `run` for blocks of up to `block` transitions of `obs`/`act`
    /// (larger blocks still go: the segment grows, once).
    pub fn open(run: &RunId, obs: usize, act: usize, block: usize) -> Result<Self, LinkError> {
        let node = node(run, "mpo-plant")?;
        let up = bytes_service(&node, run, "up", true)?
            .publisher_builder()
            .initial_max_slice_len(block_len(obs, act, block).max(1024))
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .max_loaned_samples(2)
            .create()
            .map_err(err("fleet up publisher"))?;
        let down = bytes_service(&node, run, "down", false)?
            .subscriber_builder()
            .create()
            .map_err(err("fleet down subscriber"))?;
        let notify = event(&node, run, "to-learner")?
            .notifier_builder()
            .create()
            .map_err(err("fleet notifier"))?;
        let listen = event(&node, run, "to-plants")?
            .listener_builder()
            .create()
            .map_err(err("fleet listener"))?;
        run.restrict_files();
        Ok(Self {
            up: Some(up),
            down: Some(down),
            notify: Some(notify),
            listen: Some(listen),
            node: Some(node),
            run: run.clone(),
        })
    }
}

impl PlantPort for IpcPlant {
    fn send_up(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        send(self.up.as_ref().expect("open"), frame)?;
        let _ = self.notify.as_ref().expect("open").notify();
        Ok(())
    }
    fn recv_down(&mut self, f: &mut dyn FnMut(&[u8])) -> Result<usize, LinkError> {
        drain(self.down.as_ref().expect("open"), f)
    }
    fn wait(&mut self, timeout: Duration) {
        wait_for_event(self.listen.as_ref().expect("open"), timeout);
    }
}

impl Drop for IpcPlant {
    fn drop(&mut self) {
        // Ports first, then the node; the last one out removes the run's counter segment.
        self.up = None;
        self.down = None;
        self.notify = None;
        self.listen = None;
        if let Some(n) = &self.node {
            let _ = n.try_cleanup_dead_nodes();
        }
        self.node = None;
        self.run.remove_if_last();
    }
}
