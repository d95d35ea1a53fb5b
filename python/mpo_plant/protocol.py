"""The plant protocol's messages, as ctypes structures with the bytes of the Rust side's
(`mpo-link/src/external.rs`, `docs/external-plant.md`).

Both headers are `#[repr(C)]` in Rust with no padding; the type names below are the ones the
Rust side declares, so iceoryx2 refuses to connect a plant of another layout.
"""

import ctypes

PROTOCOL_VERSION = 1

KIND_HELLO = 1
KIND_RESET = 2
KIND_STEP = 3
KIND_CLOSE = 4
KIND_BYE = 5

RESET_FRESH = 1

STATUS_OK = 0
STATUS_ERROR = 1

TASK_NAME_LEN = 64
MESSAGE_LEN = 256

# Service settings: identical on both sides (either may create the services).
BUFFER = 8
MAX_PORTS = 4


class PlantRequest(ctypes.Structure):
    """The header of every request (learner to plant); the payload is a slice of f64."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("env", ctypes.c_uint64),
        ("seed", ctypes.c_uint64),
        ("kind", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("obs_len", ctypes.c_uint32),
        ("act_len", ctypes.c_uint32),
        ("episode_steps", ctypes.c_uint32),
        ("version", ctypes.c_uint32),
        ("task", ctypes.c_uint8 * TASK_NAME_LEN),
    ]

    @staticmethod
    def type_name():
        return "mpo_link::PlantRequest/v1"


class PlantReply(ctypes.Structure):
    """The header of every reply (plant to learner); the payload is a slice of f64."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("env", ctypes.c_uint64),
        ("reward", ctypes.c_double),
        ("discount", ctypes.c_double),
        ("kind", ctypes.c_uint32),
        ("status", ctypes.c_uint32),
        ("last", ctypes.c_uint32),
        ("obs_len", ctypes.c_uint32),
        ("act_len", ctypes.c_uint32),
        ("episode_steps", ctypes.c_uint32),
        ("version", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
        ("message", ctypes.c_uint8 * MESSAGE_LEN),
    ]

    @staticmethod
    def type_name():
        return "mpo_link::PlantReply/v1"


assert ctypes.sizeof(PlantRequest) == 3 * 8 + 6 * 4 + TASK_NAME_LEN
assert ctypes.sizeof(PlantReply) == 4 * 8 + 8 * 4 + MESSAGE_LEN


def text_of(field) -> str:
    """Text from a NUL-padded byte field."""
    raw = bytes(field)
    return raw.split(b"\0", 1)[0].decode("utf-8", "replace")


def set_text(field, text: str) -> None:
    """Writes `text` into a NUL-padded byte field (cut if too long)."""
    raw = text.encode("utf-8")[: len(field)]
    ctypes.memset(ctypes.addressof(field), 0, len(field))
    ctypes.memmove(ctypes.addressof(field), raw, len(raw))


def file_prefix(run: str) -> str:
    """The iceoryx2 file prefix of a run (the Rust side's `RunId::file_prefix`)."""
    return f"iox2_mpo_{run}_"


def service_name(run: str, leaf: str) -> str:
    """The name of one of the run's plant services."""
    return f"mpo/{run}/plant/{leaf}"
