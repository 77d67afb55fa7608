"""Zenoh key expressions of camnet, built by functions only.

Every key lives under ``camnet/<rig>/``. Nodes never spell keys as string
literals; they call these functions, so a change of layout happens here once.
Ids (rig names, camera ids, node kinds and ids) are single key chunks: they
may not be empty nor contain ``/`` or Zenoh's wildcard and verbatim characters.
"""

from __future__ import annotations

from camnet.errors import InputError
from camnet.ids import validate_id

ROOT = "camnet"


def rig_prefix(rig: str) -> str:
    return f"{ROOT}/{validate_id(rig, what='rig')}"


def frame(rig: str, camera_id: str) -> str:
    """Frames of one camera (binary, see camnet.bus.frame)."""
    return f"{rig_prefix(rig)}/cam/{validate_id(camera_id, what='camera id')}/frame"


def all_frames(rig: str) -> str:
    """Selector for the frames of every camera of a rig."""
    return f"{rig_prefix(rig)}/cam/*/frame"


def features(rig: str, camera_id: str) -> str:
    """Keypoints and descriptors of one camera's frames (binary, see camnet.bus.features_wire)."""
    return f"{rig_prefix(rig)}/cam/{validate_id(camera_id, what='camera id')}/features"


def all_features(rig: str) -> str:
    """Selector for the features of every camera of a rig."""
    return f"{rig_prefix(rig)}/cam/*/features"


def observations(rig: str) -> str:
    return f"{rig_prefix(rig)}/observations"


def calibration(rig: str) -> str:
    return f"{rig_prefix(rig)}/calibration"


def calibrator(rig: str, session_id: str) -> str:
    """Liveliness token of a calibrator of a rig, named by its Zenoh session id: calibrations are taken only
    from the sessions these tokens name (camnet.bus.source)."""
    return f"{rig_prefix(rig)}/calibrator/{validate_id(session_id, what='session id')}"


def all_calibrators(rig: str) -> str:
    """Selector for the liveliness tokens of every calibrator of a rig."""
    return f"{rig_prefix(rig)}/calibrator/*"


def groundtruth(rig: str) -> str:
    return f"{rig_prefix(rig)}/groundtruth"


def lockstep_step(rig: str) -> str:
    """A lockstep replay's step announcements (JSON, see camnet.bus.lockstep)."""
    return f"{rig_prefix(rig)}/lockstep/step"


def lockstep_ack(rig: str, kind: str) -> str:
    """Acknowledgements of a lockstep node of `kind` (JSON), and its liveliness token."""
    return f"{rig_prefix(rig)}/lockstep/ack/{validate_id(kind, what='node kind')}"


def all_lockstep_acks(rig: str) -> str:
    return f"{rig_prefix(rig)}/lockstep/ack/*"


def node(rig: str, kind: str, node_id: str) -> str:
    """Liveliness token of one node (e.g. kind 'driver', id the camera id)."""
    return (
        f"{rig_prefix(rig)}/nodes/{validate_id(kind, what='node kind')}"
        f"/{validate_id(node_id, what='node id')}"
    )


def all_nodes(rig: str) -> str:
    """Selector for every node liveliness token of a rig."""
    return f"{rig_prefix(rig)}/nodes/*/*"


def node_stats(rig: str, kind: str, node_id: str) -> str:
    """Periodic statistics (JSON) of one node."""
    return f"{node(rig, kind, node_id)}/stats"


def every_rigs_nodes() -> str:
    """Selector for the node liveliness tokens of every rig on the bus."""
    return f"{ROOT}/*/nodes/*/*"


def all_node_stats(rig: str) -> str:
    return f"{rig_prefix(rig)}/nodes/*/*/stats"


def parse_node(key: str) -> tuple[str, str, str]:
    """(rig, kind, node_id) of a node liveliness key; InputError if it is not one."""
    parts = str(key).split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "nodes":
        raise InputError(f"not a camnet node key: {key!r}")
    return parts[1], parts[3], parts[4]


def parse_frame(key: str) -> tuple[str, str]:
    """(rig, camera_id) of a frame key; InputError if it is not one."""
    parts = str(key).split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "cam" or parts[4] != "frame":
        raise InputError(f"not a camnet frame key: {key!r}")
    return parts[1], parts[3]


def parse_calibrator(key: str) -> tuple[str, str]:
    """(rig, session_id) of a calibrator's liveliness key; InputError if it is not one."""
    parts = str(key).split("/")
    if len(parts) != 4 or parts[0] != ROOT or parts[2] != "calibrator":
        raise InputError(f"not a camnet calibrator key: {key!r}")
    return parts[1], parts[3]


def parse_features(key: str) -> tuple[str, str]:
    """(rig, camera_id) of a features key; InputError if it is not one."""
    parts = str(key).split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "cam" or parts[4] != "features":
        raise InputError(f"not a camnet features key: {key!r}")
    return parts[1], parts[3]
