//! Run identity, iceoryx2 configuration and the ports each side opens.
//!
//! Every run gets its own [`RunId`]. It names the services (`mpo/<id>/obs`, ...) and, through
//! the iceoryx2 file prefix, every file the run creates under `/tmp/iceoryx2` and `/dev/shm`:
//! two runs never share a service (a shared name cross-talks, and a third publisher fails), and
//! a test can check that a run left nothing behind by looking for its id.

use core::time::Duration;

use iceoryx2::config::Config;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use crate::messages::{ActMsg, MAX_BLOCKS, ObsMsg, ParamChunk};

/// Error from setting up or using the link (iceoryx2's errors flattened to text: they are
/// reported, never matched on).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinkError(pub String);

impl core::fmt::Display for LinkError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for LinkError {}

pub(crate) fn err<E: core::fmt::Debug>(what: &str) -> impl FnOnce(E) -> LinkError + '_ {
    move |e| LinkError(format!("{what}: {e:?}"))
}

/// How a side waits for the other.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WaitMode {
    /// Sleep in the kernel until notified (an event service per direction, a notify after each
    /// send). Costs a few microseconds of wake-up but leaves the core free: the default.
    Event,
    /// Spin on the subscriber. Lowest latency, burns a whole core: for isolated cores only.
    BusyPoll,
}

impl WaitMode {
    /// Parses `event` or `busy-poll`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "event" => Some(Self::Event),
            "busy-poll" | "poll" => Some(Self::BusyPoll),
            _ => None,
        }
    }
    /// The name `parse` accepts.
    pub fn name(self) -> &'static str {
        match self {
            Self::Event => "event",
            Self::BusyPoll => "busy-poll",
        }
    }
}

/// The identity of one run: `<pid>-<16 hex digits of randomness>`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunId(String);

impl RunId {
    /// A fresh id: the process id plus 64 random bits from the kernel (falling back to the
    /// clock), so neither a second run of this process nor another process can collide.
    pub fn new() -> Self {
        let mut r = [0u8; 8];
        let random = std::fs::File::open("/dev/urandom")
            .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut r))
            .map(|()| u64::from_le_bytes(r))
            .unwrap_or_else(|_| monotonic_ns() ^ (std::process::id() as u64).rotate_left(32));
        Self(format!("{}-{:016x}", std::process::id(), random))
    }

    /// Parses an id given on a command line (letters, digits and `-` only, so it is a valid
    /// service-name segment and file-name prefix).
    pub fn parse(s: &str) -> Result<Self, LinkError> {
        if s.is_empty()
            || s.len() > 40
            || !s.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-')
        {
            return Err(LinkError(format!(
                "bad run id {s:?}: 1-40 letters, digits or '-'"
            )));
        }
        Ok(Self(s.to_string()))
    }

    /// The id as text.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The iceoryx2 file prefix of this run: every shared-memory and management file of the run
    /// starts with it.
    pub fn file_prefix(&self) -> String {
        format!("iox2_mpo_{}_", self.0)
    }

    /// Every file of this run under `/dev/shm` and `/tmp/iceoryx2` (recursively): empty once
    /// the run shut down cleanly.
    pub fn files(&self) -> Vec<std::path::PathBuf> {
        let prefix = self.file_prefix();
        let mut out = Vec::new();
        let mut stack = vec![
            std::path::PathBuf::from("/dev/shm"),
            std::path::PathBuf::from("/tmp/iceoryx2"),
        ];
        while let Some(dir) = stack.pop() {
            let Ok(entries) = std::fs::read_dir(&dir) else {
                continue;
            };
            for e in entries.flatten() {
                let path = e.path();
                if e.file_name().to_string_lossy().contains(&prefix) {
                    out.push(path);
                } else if e.file_type().is_ok_and(|t| t.is_dir()) && !dir.starts_with("/dev/shm") {
                    stack.push(path);
                }
            }
        }
        out
    }

    /// Takes the group's and others' permissions off every file of this run. iceoryx2 makes
    /// its node counter (`*.global_mgmt`) readable and writable by everyone, as it is shared
    /// by every user of a domain; with a per-run prefix the domain is the run, which is its
    /// user's alone (its other files are created owner-only). Each side calls this once its
    /// services are open, so the window in which the counter is open to others is the time
    /// it takes to open them.
    pub fn restrict_files(&self) {
        use std::os::unix::fs::PermissionsExt;
        for f in self.files() {
            let Ok(meta) = std::fs::symlink_metadata(&f) else {
                continue;
            };
            let mode = meta.permissions().mode();
            if meta.is_file() && mode & 0o077 != 0 {
                let _ =
                    std::fs::set_permissions(&f, std::fs::Permissions::from_mode(mode & !0o077));
            }
        }
    }

    /// Removes iceoryx2's persistent node counter of this run once no other file of the run
    /// remains (every live node and service has files, so none is left: this side was the
    /// last one). iceoryx2 keeps that segment forever by design, as it is shared by every node
    /// of a domain; with a per-run prefix the domain is the run, so the last one out removes
    /// it.
    pub fn remove_if_last(&self) {
        let files = self.files();
        let global = |p: &std::path::PathBuf| p.extension().is_some_and(|e| e == "global_mgmt");
        if !files.is_empty() && files.iter().all(global) {
            for f in files {
                let _ = std::fs::remove_file(f);
            }
        }
    }

    /// An iceoryx2 configuration private to this run (its own file prefix).
    pub fn config(&self) -> Result<Config, LinkError> {
        let mut cfg = Config::global_config().clone();
        cfg.global.prefix =
            FileName::new(self.file_prefix().as_bytes()).map_err(err("file prefix"))?;
        Ok(cfg)
    }

    fn service_name(&self, leaf: &str) -> Result<ServiceName, LinkError> {
        ServiceName::new(&format!("mpo/{}/{leaf}", self.0)).map_err(err("service name"))
    }
}

impl Default for RunId {
    fn default() -> Self {
        Self::new()
    }
}

/// Waits until `listener` has an event or `timeout` has passed (or a signal arrived), then
/// drains its pending events; the caller then drains its subscribers.
///
/// Both sides wait this way rather than with `Listener::timed_wait`, whose timeout goes through
/// the socket layer and is rounded up to whole jiffies (a 500 us deadline became 8 ms here), or
/// a `WaitSet`, which allocates a small vector on every wait (the same speed otherwise: event
/// round trip p50 28.3-29.7 us either way, A/B on this machine): `ppoll` on the listener's
/// descriptor times out on a high-resolution timer and allocates nothing. Coalesced wake-ups
/// are fine, as the subscribers are drained after each.
pub fn wait_for_event<S: iceoryx2::service::Service>(listener: &Listener<S>, timeout: Duration)
where
    Listener<S>: FileDescriptorBased,
{
    // SAFETY: the descriptor is only polled while `listener` owns it.
    let fd = unsafe { listener.file_descriptor().native_handle() };
    let mut pfd = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    let ts = libc::timespec {
        tv_sec: timeout.as_secs() as libc::time_t,
        tv_nsec: timeout.subsec_nanos() as libc::c_long,
    };
    // SAFETY: one valid pollfd and timespec; a signal (no `SA_RESTART`) just ends the wait early.
    unsafe { libc::ppoll(&mut pfd, 1, &ts, core::ptr::null()) };
    let _ = listener.try_wait(|_| {});
}

/// `CLOCK_MONOTONIC` in nanoseconds: the same clock in both processes, so timestamps in the
/// messages can be compared across the link.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// The services of one run, opened (or created, whichever side comes first) with identical
/// settings so either side may start first.
pub(crate) struct Services {
    pub node: Node<ipc::Service>,
    obs: iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, ObsMsg, ()>,
    act: iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, ActMsg, ()>,
    params: iceoryx2::service::port_factory::publish_subscribe::PortFactory<
        ipc::Service,
        ParamChunk,
        (),
    >,
    to_controller: iceoryx2::service::port_factory::event::PortFactory<ipc::Service>,
    to_plant: iceoryx2::service::port_factory::event::PortFactory<ipc::Service>,
}

impl Services {
    /// Creates this side's node and opens the five services of `run`.
    ///
    /// Signal handling is disabled in iceoryx2: the controller installs its own SIGINT/SIGTERM
    /// flag (iceoryx2's waits would otherwise consume the signal and nobody would act on it), and the
    /// plant lives inside a host that has its own Ctrl-C handling.
    pub fn open(run: &RunId, side: &str) -> Result<Self, LinkError> {
        // Warnings (such as "no config file was loaded") are noise here; IOX2_LOG_LEVEL still
        // overrides.
        iceoryx2::prelude::set_log_level_from_env_or(LogLevel::Error);
        let cfg = run.config()?;
        let node = NodeBuilder::new()
            .config(&cfg)
            .name(&NodeName::new(&format!("mpo-{side}")).map_err(err("node name"))?)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(err("node"))?;
        // Observations and actions: only the newest one matters, so small buffers that
        // overwrite the oldest entry; no history (a new controller must not answer old
        // requests).
        let obs = pub_sub::<ObsMsg>(&node, run, "obs", 4, 0)?;
        let act = pub_sub::<ActMsg>(&node, run, "act", 4, 0)?;
        // Parameters: the history keeps the newest complete generation, so a controller that
        // (re)starts after a push still receives it.
        let params = pub_sub::<ParamChunk>(&node, run, "params", MAX_BLOCKS, MAX_BLOCKS)?;
        let to_controller = node
            .service_builder(&run.service_name("to-controller")?)
            .event()
            .max_notifiers(4)
            .max_listeners(4)
            .open_or_create()
            .map_err(err("event service"))?;
        let to_plant = node
            .service_builder(&run.service_name("to-plant")?)
            .event()
            .max_notifiers(4)
            .max_listeners(4)
            .open_or_create()
            .map_err(err("event service"))?;
        run.restrict_files();
        Ok(Self {
            node,
            obs,
            act,
            params,
            to_controller,
            to_plant,
        })
    }

    /// Subscribers attached to the observation service (controllers).
    pub fn obs_subscribers(&self) -> usize {
        self.obs.dynamic_config().number_of_subscribers()
    }

    /// Removes what killed peers left registered (their ports count against the service
    /// limits and their files stay until someone cleans up).
    pub fn cleanup_dead(&self) {
        let _ = self.node.try_cleanup_dead_nodes();
    }
}

/// The plant's ports: publishes observations and parameters, receives actions.
pub struct PlantPorts {
    /// Observations out.
    pub obs: Publisher<ipc::Service, ObsMsg, ()>,
    /// Parameter blocks out.
    pub params: Publisher<ipc::Service, ParamChunk, ()>,
    /// Actions in.
    pub act: Subscriber<ipc::Service, ActMsg, ()>,
    /// Wakes the controller after a send.
    pub notify: Notifier<ipc::Service>,
    /// Woken by the controller's replies.
    pub listen: Listener<ipc::Service>,
    pub(crate) services: Services,
}

impl PlantPorts {
    /// Opens the plant side of `run`.
    pub fn open(run: &RunId) -> Result<Self, LinkError> {
        let services = Services::open(run, "plant")?;
        Ok(Self {
            obs: services
                .obs
                .publisher_builder()
                .create()
                .map_err(err("obs publisher"))?,
            params: services
                .params
                .publisher_builder()
                .max_loaned_samples(2)
                .create()
                .map_err(err("params publisher"))?,
            act: services
                .act
                .subscriber_builder()
                .create()
                .map_err(err("act subscriber"))?,
            notify: services
                .to_controller
                .notifier_builder()
                .create()
                .map_err(err("notifier"))?,
            listen: services
                .to_plant
                .listener_builder()
                .create()
                .map_err(err("listener"))?,
            services,
        })
    }

    /// Clears dead peers' registrations (after a controller was killed).
    pub fn cleanup_dead(&self) {
        self.services.cleanup_dead();
    }
}

/// The controller's ports: receives observations and parameters, publishes actions.
pub struct ControllerPorts {
    /// Observations in.
    pub obs: Subscriber<ipc::Service, ObsMsg, ()>,
    /// Parameter blocks in.
    pub params: Subscriber<ipc::Service, ParamChunk, ()>,
    /// Actions out.
    pub act: Publisher<ipc::Service, ActMsg, ()>,
    /// Wakes the plant after a reply.
    pub notify: Notifier<ipc::Service>,
    /// Woken by the plant's sends.
    pub listen: Listener<ipc::Service>,
    pub(crate) services: Services,
}

impl ControllerPorts {
    /// Opens the controller side of `run`.
    pub fn open(run: &RunId) -> Result<Self, LinkError> {
        let services = Services::open(run, "controller")?;
        let ports = Self::create(services)?;
        // A previous controller of this run that was killed still holds ports: cleaned up
        // only after ours exist. Cleaned up first, a restarted controller sometimes never
        // received the plant's observations (4 of 22 runs of the two restart tests of
        // tests/controller.rs on a loaded 2-core machine; 0 of 26 in this order). The likely
        // cause: our port took the dead port's freed slot while the plant's publisher still
        // held its connection to the dead one. The limit of 4 ports leaves room for it.
        ports.services.cleanup_dead();
        Ok(ports)
    }

    fn create(services: Services) -> Result<Self, LinkError> {
        Ok(Self {
            obs: services
                .obs
                .subscriber_builder()
                .create()
                .map_err(err("obs subscriber"))?,
            params: services
                .params
                .subscriber_builder()
                .create()
                .map_err(err("params subscriber"))?,
            act: services
                .act
                .publisher_builder()
                .create()
                .map_err(err("act publisher"))?,
            notify: services
                .to_plant
                .notifier_builder()
                .create()
                .map_err(err("notifier"))?,
            listen: services
                .to_controller
                .listener_builder()
                .create()
                .map_err(err("listener"))?,
            services,
        })
    }

    /// The node (for WaitSets and cleanup).
    pub fn node(&self) -> &Node<ipc::Service> {
        &self.services.node
    }
}

/// Time left until `deadline_ns` (zero when passed).
pub(crate) fn remaining(deadline_ns: u64) -> Duration {
    Duration::from_nanos(deadline_ns.saturating_sub(monotonic_ns()))
}

/// Opens (or creates) the run's publish-subscribe service `name` for `T`: overflow drops the
/// oldest sample, `buffer` samples per subscriber, `history` kept for late subscribers.
fn pub_sub<T: std::fmt::Debug + ZeroCopySend>(
    node: &Node<ipc::Service>,
    run: &RunId,
    name: &str,
    buffer: usize,
    history: usize,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>,
    LinkError,
> {
    let what = format!("{name} service");
    node.service_builder(&run.service_name(name)?)
        .publish_subscribe::<T>()
        .enable_safe_overflow(true)
        .subscriber_max_buffer_size(buffer)
        .history_size(history)
        .max_publishers(4)
        .max_subscribers(4)
        .open_or_create()
        .map_err(err(&what))
}
