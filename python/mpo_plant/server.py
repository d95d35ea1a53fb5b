"""The plant's end of the protocol: answers the learner's requests until it says BYE."""

import ctypes
import math
import os
import sys
import time
import traceback

import numpy as np

from . import protocol as p


class PlantFailed(Exception):
    """A request the plant cannot serve (its text goes back to the learner)."""


def _sizes(plant):
    """The sizes and bounds a plant object declares (see `serve`)."""
    obs, act = int(plant.obs_size), int(plant.act_size)
    low = getattr(plant, "action_low", None)
    high = getattr(plant, "action_high", None)
    low = np.full(act, -math.inf) if low is None else np.asarray(low, dtype=np.float64)
    high = np.full(act, math.inf) if high is None else np.asarray(high, dtype=np.float64)
    low, high = np.broadcast_to(low.ravel(), (act,)), np.broadcast_to(high.ravel(), (act,))
    steps = int(getattr(plant, "episode_steps", 0) or 0)
    name = str(getattr(plant, "name", type(plant).__name__))
    return obs, act, np.concatenate([low, high]), steps, name


class _Ports:
    """The plant's ports on the run's four services."""

    def __init__(self, run: str, max_reply_len: int):
        import iceoryx2 as iox2

        self.iox2 = iox2
        self.run = run
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        cfg = iox2.config.default()
        cfg.global_cfg.prefix = iox2.FileName.new(p.file_prefix(run))
        self.node = (
            iox2.NodeBuilder.new()
            .config(cfg)
            .name(iox2.NodeName.new("mpo-plant"))
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )

        def slices(leaf, header):
            return (
                self.node.service_builder(iox2.ServiceName.new(p.service_name(run, leaf)))
                .publish_subscribe(iox2.Slice[ctypes.c_double])
                .user_header(header)
                .enable_safe_overflow(True)
                .subscriber_max_buffer_size(p.BUFFER)
                .history_size(0)
                .max_publishers(p.MAX_PORTS)
                .max_subscribers(p.MAX_PORTS)
                .open_or_create()
            )

        def event(leaf):
            return (
                self.node.service_builder(iox2.ServiceName.new(p.service_name(run, leaf)))
                .event()
                .max_notifiers(p.MAX_PORTS)
                .max_listeners(p.MAX_PORTS)
                .open_or_create()
            )

        self.requests = slices("request", p.PlantRequest).subscriber_builder().create()
        self.replies = (
            slices("reply", p.PlantReply)
            .publisher_builder()
            .initial_max_slice_len(max(1, max_reply_len))
            .create()
        )
        self.listen = event("to-plant").listener_builder().create()
        self.notify = event("to-learner").notifier_builder().create()

    def close(self):
        """Releases the ports and the node, clears what a killed learner left, and removes
        the run's last file (iceoryx2's node counter) when nobody else holds the run."""
        self.node.try_cleanup_dead_nodes()
        for port in (self.requests, self.replies, self.listen, self.notify):
            port.delete()
        del self.requests, self.replies, self.listen, self.notify, self.node
        import gc

        gc.collect()
        files = _run_files(self.run)
        if files and all(f.endswith(".global_mgmt") for f in files):
            for f in files:
                try:
                    os.remove(f)
                except OSError:
                    pass

    def receive(self, timeout_s: float):
        """The next request as (header copy, payload copy), or None after `timeout_s`."""
        sample = self.requests.receive()
        if sample is None:
            self.listen.timed_wait(self.iox2.Duration.from_secs_f64(timeout_s))
            sample = self.requests.receive()
            if sample is None:
                return None
        header = p.PlantRequest.from_buffer_copy(sample.user_header().contents)
        # The element count from the sample's header: the bindings' `Slice.len()` of a
        # received slice is its length in bytes (iceoryx2 0.10.0).
        n = sample.header.number_of_elements
        payload = np.empty(n, dtype=np.float64)
        if n:
            ctypes.memmove(payload.ctypes.data, sample.payload_ptr, 8 * n)
        del sample
        return header, payload

    def reply(self, request, values=None, **fields):
        """Sends the reply to `request`: `fields` into its header, `values` as its payload."""
        values = np.zeros(0) if values is None else np.ascontiguousarray(values, np.float64)
        sample = self.replies.loan_slice_uninit(len(values))
        h = sample.user_header().contents
        ctypes.memset(ctypes.addressof(h), 0, ctypes.sizeof(p.PlantReply))
        h.seq, h.env, h.kind = request.seq, request.env, request.kind
        for k, v in fields.items():
            if k == "message":
                p.set_text(h.message, v)
            else:
                setattr(h, k, v)
        if len(values):
            ctypes.memmove(sample.payload_ptr, values.ctypes.data, values.nbytes)
        sample.assume_init().send()
        self.notify.notify()


def _run_files(run):
    """Every file of the run under /dev/shm and /tmp/iceoryx2 (the Rust side's
    `RunId::files`)."""
    prefix = p.file_prefix(run)
    out = []
    for top in ("/dev/shm", "/tmp/iceoryx2"):
        for dirpath, dirnames, filenames in os.walk(top):
            out += [os.path.join(dirpath, n) for n in filenames + dirnames if prefix in n]
            if top == "/dev/shm":
                dirnames.clear()
    return out


def _parent_gone(parent) -> bool:
    if parent is None:
        return False
    try:
        os.kill(parent, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def serve(
    make_env,
    run=None,
    *,
    single_instance=False,
    keep_serving=False,
    idle_timeout=None,
    log=sys.stderr,
):
    """Serves plants made by `make_env()` to the learner of run `run` until it says BYE.

    `make_env()` returns a plant object with:

    - `obs_size`, `act_size` (ints): the sizes; they must equal the task file's
      `[external] obs, act`;
    - `reset(seed)`: starts an episode and returns the first observation (a sequence of
      `obs_size` numbers); `seed` is an int for a fresh instance's first reset, None after;
    - `step(action)`: applies the action (a float64 numpy array of `act_size` values, in
      the plant's units: already mapped from the policy's [-1, 1] onto the task file's
      bounds) and returns `(observation, reward, terminated, truncated)`;
    - optionally `action_low`, `action_high` (per dimension or one number; checked against
      the task file's), `episode_steps` (checked against the task file's), `name` (shown in
      the learner's messages) and `close()`.

    Each environment instance the learner asks for (the training environment, a fresh one
    per evaluation episode) gets its own `make_env()`, unless `single_instance` (a real
    robot: every instance is the one plant). `run` defaults to the environment variable
    `MPO_PLANT_RUN` (set by `mpo train` when it starts the plant's program). With
    `keep_serving`, a BYE does not end `serve`: the next learner of the same run id is
    served too. When the learner started this program (`MPO_PLANT_PARENT`), it ends when the
    learner is gone; `idle_timeout` (seconds without a request) ends it in any case.
    """
    run = run or os.environ.get("MPO_PLANT_RUN")
    if not run:
        raise SystemExit("mpo_plant: no run id: pass --run RUN_ID or set MPO_PLANT_RUN")
    parent = os.environ.get("MPO_PLANT_PARENT")
    parent = int(parent) if parent else None
    server = _Server(make_env, run, single_instance, log)
    try:
        last_request = time.monotonic()
        while True:
            got = server.ports.receive(0.1)
            if got is None:
                if _parent_gone(parent):
                    print("mpo_plant: the learner is gone; exiting", file=log)
                    break
                idle = time.monotonic() - last_request
                if idle_timeout is not None and idle > idle_timeout:
                    print(f"mpo_plant: no request for {idle_timeout} s; exiting", file=log)
                    break
                continue
            last_request = time.monotonic()
            if not server.handle(*got) and not keep_serving:
                break
    finally:
        server.close()


class _Server:
    """The plant instances of one run and the answers to each request."""

    def __init__(self, make_env, run, single_instance, log):
        self.make_env, self.run, self.single, self.log = make_env, run, single_instance, log
        # The plant made for the sizes serves the first instance (a robot's only one).
        self.first = make_env()
        self.obs_size, self.act_size, self.bounds, self.steps, self.name = _sizes(self.first)
        self.unused = [self.first]
        self.envs = {}
        self.greeted = False
        self.ports = _Ports(run, max(self.obs_size, 2 * self.act_size))

    def handle(self, req, payload) -> bool:
        """Answers one request; False after BYE."""
        kind = req.kind
        if kind == p.KIND_HELLO:
            self.hello(req)
        elif kind in (p.KIND_RESET, p.KIND_STEP):
            try:
                values, fields = self.episode(req, payload)
            except Exception as e:  # noqa: BLE001 - every failure goes back as text
                traceback.print_exc(file=self.log)
                self.ports.reply(req, status=p.STATUS_ERROR, message=f"{type(e).__name__}: {e}")
                return True
            self.ports.reply(req, values, **fields)
        elif kind == p.KIND_CLOSE:
            env = self.envs.pop(req.env, None)
            if env is not None and not self.single:
                _close(env)
        elif kind == p.KIND_BYE:
            if not self.single:
                for env in self.envs.values():
                    _close(env)
            self.envs.clear()
            self.greeted = False
            return False
        return True

    def hello(self, req):
        if not self.greeted:
            print(
                f"mpo_plant: serving {self.name} (obs {self.obs_size}, act {self.act_size}) "
                f"to task {p.text_of(req.task)} (obs {req.obs_len}, act {req.act_len}), "
                f"run {self.run}",
                file=self.log,
                flush=True,
            )
            self.greeted = True
        self.ports.reply(
            req,
            self.bounds,
            obs_len=self.obs_size,
            act_len=self.act_size,
            episode_steps=self.steps,
            version=p.PROTOCOL_VERSION,
            message=self.name,
        )

    def episode(self, req, payload):
        """RESET or STEP of one instance: (observation, reply fields)."""
        if req.kind == p.KIND_RESET and req.env not in self.envs:
            if not req.flags & p.RESET_FRESH:
                raise PlantFailed(f"instance {req.env} was never reset fresh")
            if self.single:
                self.envs[req.env] = self.first
            else:
                self.envs[req.env] = self.unused.pop() if self.unused else self.make_env()
        env = self.envs.get(req.env)
        if env is None:
            raise PlantFailed(f"STEP of instance {req.env} before its RESET")
        if req.kind == p.KIND_RESET:
            fresh = bool(req.flags & p.RESET_FRESH)
            obs, fields = env.reset(int(req.seed) if fresh else None), {}
        else:
            obs, reward, terminated, truncated = env.step(payload)
            fields = {
                "reward": float(reward),
                "discount": 0.0 if terminated else 1.0,
                "last": 1 if (terminated or truncated) else 0,
            }
        values = np.asarray(obs, dtype=np.float64).ravel()
        if len(values) != self.obs_size:
            what = "reset" if req.kind == p.KIND_RESET else "step"
            raise PlantFailed(
                f"{what} returned an observation of {len(values)} values; the plant declared "
                f"obs_size = {self.obs_size}"
            )
        return values, fields

    def close(self):
        left = [*self.envs.values(), *self.unused, *([self.first] if self.single else [])]
        for env in {id(e): e for e in left}.values():
            _close(env)
        self.ports.close()


def _close(env):
    close = getattr(env, "close", None)
    if close is not None:
        close()
