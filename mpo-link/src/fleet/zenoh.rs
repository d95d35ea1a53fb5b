//! The fleet over zenoh, between hosts (the `zenoh` feature): the same frames as over
//! iceoryx2, published on two key expressions of the run, `mpo/<run>/down` (the learner
//! publishes, every plant subscribes) and `mpo/<run>/up` (every plant publishes, the learner
//! subscribes).
//!
//! Both ends are zenoh peers with multicast and gossip scouting off: the learner listens on
//! its endpoints (`tcp/ADDR:PORT`, or `tls/ADDR:PORT` with mutual certificates), each plant
//! connects to them, so no router runs and plants never connect to each other. zenoh runs its
//! own threads; this module only uses its blocking calls (`Wait`) and reads received frames
//! from ring channels, so neither side needs an async runtime of its own.
//!
//! Received frames wait in a ring channel per subscriber that drops the oldest when full,
//! as iceoryx2's buffers do: a learner busy learning never holds up a free-running plant's
//! link, and a plant that falls far behind loses old frames, not the newest. Sends block
//! while zenoh's transmit queue is full (`CongestionControl::Block`): a parameter block is
//! never dropped on the sender's side.

use core::time::Duration;
use std::collections::VecDeque;

use ::zenoh::Wait;
use ::zenoh::handlers::{RingChannel, RingChannelHandler};
use ::zenoh::pubsub::{Publisher, Subscriber};
use ::zenoh::qos::CongestionControl;
use ::zenoh::sample::Sample;
use ::zenoh::{Config, Session};

use super::{LearnerPort, PlantPort, Remote};
use crate::service::{LinkError, RunId};

/// Frames the learner's subscriber holds per plant it expects (as [`super::ipc::UP_BUFFER`]).
pub const UP_BUFFER: usize = 16;
/// Frames a plant's subscriber holds: a whole parameter generation (at most 32 blocks) with
/// room to spare.
pub const DOWN_BUFFER: usize = 128;
/// How long a closing side lets its last frames (the learner's STOP) leave before its
/// session closes.
const LINGER: Duration = Duration::from_millis(300);

fn zerr(what: &str) -> impl Fn(::zenoh::Error) -> LinkError + '_ {
    move |e| LinkError(format!("zenoh: {what}: {e}"))
}

/// A JSON string (endpoints and file names go into zenoh's JSON5 configuration).
fn quoted(s: &str) -> String {
    let mut o = String::with_capacity(s.len() + 2);
    o.push('"');
    for c in s.chars() {
        match c {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            c if (c as u32) < 0x20 => o.push_str(&format!("\\u{:04x}", c as u32)),
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

fn list(items: &[String]) -> String {
    let q: Vec<String> = items.iter().map(|s| quoted(s)).collect();
    format!("[{}]", q.join(","))
}

fn path_text(p: &std::path::Path) -> Result<String, LinkError> {
    p.to_str()
        .map(quoted)
        .ok_or_else(|| LinkError(format!("zenoh: a file name that is not UTF-8: {p:?}")))
}

/// Checks `remote`: at least one endpoint, `tls/` endpoints exactly when certificates are
/// given, and the certificate files readable.
pub fn check(remote: &Remote) -> Result<(), LinkError> {
    if remote.endpoints.is_empty() {
        return Err(LinkError("no zenoh endpoint given".into()));
    }
    for e in &remote.endpoints {
        let tls = e.starts_with("tls/");
        if !tls && !e.starts_with("tcp/") {
            return Err(LinkError(format!(
                "zenoh endpoint {e:?}: expected tcp/ADDR:PORT or tls/ADDR:PORT"
            )));
        }
        match (&remote.tls, tls) {
            (None, true) => {
                return Err(LinkError(format!(
                    "the endpoint {e} needs certificates (--fleet-ca, --fleet-cert, --fleet-key)"
                )));
            }
            (Some(_), false) => {
                return Err(LinkError(format!(
                    "certificates are given but {e} is not a tls/ endpoint: the link would not be encrypted"
                )));
            }
            _ => {}
        }
    }
    if let Some(t) = &remote.tls {
        for (what, p) in [("CA", &t.ca), ("certificate", &t.cert), ("key", &t.key)] {
            std::fs::metadata(p)
                .map_err(|e| LinkError(format!("the fleet's TLS {what} {}: {e}", p.display())))?;
        }
    }
    Ok(())
}

/// The zenoh configuration of a learner (`listen`) or a plant (not `listen`: it connects).
pub fn config(remote: &Remote, listen: bool) -> Result<Config, LinkError> {
    check(remote)?;
    let mut c = Config::default();
    let mut set = |k: &str, v: &str| {
        c.insert_json5(k, v)
            .map_err(|e| LinkError(format!("zenoh configuration {k} = {v}: {e}")))
    };
    set("mode", "\"peer\"")?;
    set("scouting/multicast/enabled", "false")?;
    set("scouting/gossip/enabled", "false")?;
    let eps = list(&remote.endpoints);
    if listen {
        set("listen/endpoints", &eps)?;
        set("connect/endpoints", "[]")?;
    } else {
        set("listen/endpoints", "[]")?;
        set("connect/endpoints", &eps)?;
        let ms = remote.connect_timeout.as_millis().max(1);
        set("connect/timeout_ms", &ms.to_string())?;
        set("connect/exit_on_failure", "true")?;
    }
    if let Some(t) = &remote.tls {
        let (ca, cert, key) = (path_text(&t.ca)?, path_text(&t.cert)?, path_text(&t.key)?);
        let tls = format!(
            "{{root_ca_certificate:{ca},listen_certificate:{cert},listen_private_key:{key},\
             connect_certificate:{cert},connect_private_key:{key},enable_mtls:true,\
             verify_name_on_connect:true}}"
        );
        set("transport/link/tls", &tls)?;
    }
    Ok(c)
}

fn key(run: &RunId, leaf: &str) -> String {
    format!("mpo/{}/{leaf}", run.as_str())
}

fn open(remote: &Remote, listen: bool) -> Result<Session, LinkError> {
    let c = config(remote, listen)?;
    ::zenoh::open(c).wait().map_err(|e| {
        let what = match listen {
            true => format!("listening on {}", remote.endpoints.join(", ")),
            false => format!("reaching the learner at {}", remote.endpoints.join(", ")),
        };
        LinkError(format!("zenoh: {what}: {e}"))
    })
}

/// Frames received, with the one [`Ends::wait`] took early.
struct Ends {
    publisher: Option<Publisher<'static>>,
    subscriber: Option<Subscriber<RingChannelHandler<Sample>>>,
    pending: VecDeque<Sample>,
    session: Option<Session>,
}

impl Ends {
    fn new(
        session: Session,
        run: &RunId,
        (publish, subscribe): (&str, &str),
        buffer: usize,
    ) -> Result<Self, LinkError> {
        let publisher = session
            .declare_publisher(key(run, publish))
            .congestion_control(CongestionControl::Block)
            .express(true)
            .wait()
            .map_err(zerr("publisher"))?;
        let subscriber = session
            .declare_subscriber(key(run, subscribe))
            .with(RingChannel::new(buffer))
            .wait()
            .map_err(zerr("subscriber"))?;
        Ok(Self {
            publisher: Some(publisher),
            subscriber: Some(subscriber),
            pending: VecDeque::new(),
            session: Some(session),
        })
    }

    fn send(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        self.publisher
            .as_ref()
            .expect("open until dropped")
            .put(frame.to_vec())
            .wait()
            .map_err(zerr("send a frame"))
    }

    fn drain(&mut self, f: &mut dyn FnMut(&[u8])) -> Result<usize, LinkError> {
        let mut n = 0;
        while let Some(s) = self.pending.pop_front() {
            f(&s.payload().to_bytes());
            n += 1;
        }
        let sub = self.subscriber.as_ref().expect("open until dropped");
        while let Some(s) = sub.try_recv().map_err(zerr("receive a frame"))? {
            f(&s.payload().to_bytes());
            n += 1;
        }
        Ok(n)
    }

    fn wait(&mut self, timeout: Duration) {
        if !self.pending.is_empty() {
            return;
        }
        let sub = self.subscriber.as_ref().expect("open until dropped");
        match sub.recv_timeout(timeout) {
            Ok(Some(s)) => self.pending.push_back(s),
            Ok(None) => {}
            // Closed: nothing will come; do not spin.
            Err(_) => std::thread::sleep(timeout),
        }
    }
}

impl Drop for Ends {
    fn drop(&mut self) {
        std::thread::sleep(LINGER);
        if let Some(p) = self.publisher.take() {
            let _ = p.undeclare().wait();
        }
        if let Some(s) = self.subscriber.take() {
            let _ = s.undeclare().wait();
        }
        if let Some(s) = self.session.take() {
            let _ = s.close().wait();
        }
    }
}

/// The learner's end over zenoh: listens on the endpoints, publishes `down`, subscribes
/// `up`.
pub struct ZenohLearner {
    ends: Ends,
}

impl ZenohLearner {
    /// Listens on `remote`'s endpoints for the plants of `run` (up to `plants` of them
    /// sizes its receive buffer).
    pub fn open(run: &RunId, remote: &Remote, plants: usize) -> Result<Self, LinkError> {
        let session = open(remote, true)?;
        let ends = Ends::new(session, run, ("down", "up"), UP_BUFFER * plants.max(1))?;
        Ok(Self { ends })
    }
}

impl LearnerPort for ZenohLearner {
    fn send_down(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        self.ends.send(frame)
    }
    fn recv_up(&mut self, f: &mut dyn FnMut(&[u8])) -> Result<usize, LinkError> {
        self.ends.drain(f)
    }
    fn wait(&mut self, timeout: Duration) {
        self.ends.wait(timeout)
    }
    fn name(&self) -> &'static str {
        "zenoh"
    }
}

/// A plant's end over zenoh: connects to the learner's endpoints, publishes `up`, subscribes
/// `down`.
pub struct ZenohPlant {
    ends: Ends,
}

impl ZenohPlant {
    /// Connects to the learner of `run` at `remote`'s endpoints (failing after its
    /// `connect_timeout` when none answers, or when the TLS handshake is refused).
    pub fn open(run: &RunId, remote: &Remote) -> Result<Self, LinkError> {
        let session = open(remote, false)?;
        let ends = Ends::new(session, run, ("up", "down"), DOWN_BUFFER)?;
        Ok(Self { ends })
    }
}

impl PlantPort for ZenohPlant {
    fn send_up(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        self.ends.send(frame)
    }
    fn recv_down(&mut self, f: &mut dyn FnMut(&[u8])) -> Result<usize, LinkError> {
        self.ends.drain(f)
    }
    fn wait(&mut self, timeout: Duration) {
        self.ends.wait(timeout)
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::fleet::TlsFiles;

    #[test]
    fn tls_endpoints_need_certificates_and_certificates_need_tls() {
        let tcp = Remote {
            endpoints: vec!["tcp/127.0.0.1:7447".into()],
            tls: None,
            connect_timeout: Duration::from_secs(10),
        };
        check(&tcp).unwrap();
        let bare_tls = Remote {
            endpoints: vec!["tls/127.0.0.1:7447".into()],
            tls: None,
            connect_timeout: Duration::from_secs(10),
        };
        assert!(
            check(&bare_tls)
                .unwrap_err()
                .0
                .contains("needs certificates")
        );
        let files = TlsFiles {
            ca: PathBuf::from("/nonexistent/ca.pem"),
            cert: PathBuf::from("/nonexistent/c.pem"),
            key: PathBuf::from("/nonexistent/k.pem"),
        };
        let mixed = Remote {
            endpoints: vec!["tcp/127.0.0.1:7447".into()],
            tls: Some(files),
            connect_timeout: Duration::from_secs(10),
        };
        assert!(check(&mixed).unwrap_err().0.contains("not a tls/ endpoint"));
        let udp = Remote {
            endpoints: vec!["udp/127.0.0.1:7447".into()],
            tls: None,
            connect_timeout: Duration::from_secs(10),
        };
        assert!(check(&udp).is_err());
        assert!(config(&tcp, true).is_ok());
        assert!(config(&tcp, false).is_ok());
    }

    #[test]
    fn a_frame_goes_down_and_up_over_loopback() {
        let run = RunId::new();
        // A free port: bind one, let it go, listen there.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let remote = Remote {
            endpoints: vec![format!("tcp/127.0.0.1:{port}")],
            tls: None,
            connect_timeout: Duration::from_secs(10),
        };
        let mut learner = ZenohLearner::open(&run, &remote, 1).unwrap();
        let mut plant = ZenohPlant::open(&run, &remote).unwrap();
        let t0 = std::time::Instant::now();
        let mut got = Vec::new();
        // Declarations take a moment to reach the other side: repeat until heard.
        while got.is_empty() {
            assert!(t0.elapsed() < Duration::from_secs(20), "nothing came up");
            plant.send_up(b"hello up").unwrap();
            learner.wait(Duration::from_millis(100));
            learner.recv_up(&mut |f| got.push(f.to_vec())).unwrap();
        }
        assert_eq!(got[0], b"hello up");
        let big: Vec<u8> = (0..100_000u32).map(|i| i as u8).collect();
        learner.send_down(&big).unwrap();
        let mut down = Vec::new();
        while down.is_empty() {
            assert!(t0.elapsed() < Duration::from_secs(20), "nothing came down");
            plant.wait(Duration::from_millis(100));
            plant.recv_down(&mut |f| down.push(f.to_vec())).unwrap();
        }
        assert_eq!(down[0], big);
    }
}
