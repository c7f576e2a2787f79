"""Every wire type of the system, split by domain, re-exported here.

Import message types from ``common.messages``; each domain module declares
its own types on the shared :class:`~common.messages.base.Message` base.
"""

from common.messages.agent import *  # noqa: F403 - every agent-context and runner wire type
from common.messages.agent import __all__ as _agent_all
from common.messages.audit import *  # noqa: F403 - every audit-trail wire type
from common.messages.audit import __all__ as _audit_all
from common.messages.auth import (
    ALL_PERMISSIONS,
    AuthEnvelope,
    Permission,
    SessionToken,
    SignedToken,
)
from common.messages.base import (
    MAX_MESSAGE_BYTES,
    ErrorCode,
    ErrorReply,
    Ident,
    Message,
    MessageError,
    OkReply,
    PackedArray,
    all_message_types,
    decode,
    encode,
)
from common.messages.camera import *  # noqa: F403 - every camera wire type
from common.messages.camera import __all__ as _camera_all
from common.messages.chat import *  # noqa: F403 - every chat wire type
from common.messages.chat import __all__ as _chat_all
from common.messages.grading import *  # noqa: F403 - every grader wire type
from common.messages.grading import __all__ as _grading_all
from common.messages.host import *  # noqa: F403 - every host wire type
from common.messages.host import __all__ as _host_all
from common.messages.lti import *  # noqa: F403 - every LTI wire type
from common.messages.lti import __all__ as _lti_all
from common.messages.recording import *  # noqa: F403 - every recording wire type
from common.messages.recording import __all__ as _recording_all
from common.messages.registry import *  # noqa: F403 - every registry wire type
from common.messages.registry import __all__ as _registry_all
from common.messages.twin import *  # noqa: F403 - every twin wire type
from common.messages.twin import __all__ as _twin_all
from common.messages.world import (
    FINGERS_CLOSED,
    FINGERS_HOLDING,
    FINGERS_OPEN,
    MAC_ITEM_BYTES,
    MAC_ITEM_COUNTERS,
    MAC_ITEM_DTYPE,
    MAC_ITEM_SPEEDS,
    MAC_ITEM_STRUCT,
    MAX_BUNDLED,
    AddItem,
    AgentCommand,
    AgentInfo,
    AgentStates,
    BundledCommand,
    CommandBundle,
    EditResult,
    FloorLineInfo,
    GripperReading,
    ItemInfo,
    Lease,
    LightInfo,
    MacCommand,
    MacCommandBundle,
    MapRequest,
    MoveItem,
    RemoveItem,
    ResetAgent,
    ResizeArena,
    RobotLook,
    RobotTypeInfo,
    RobotTypeReply,
    RobotTypeRequest,
    RotateItem,
    SampleBundle,
    SensorBatch,
    SensorSample,
    ShapeInfo,
    WorldEdit,
    WorldFrame,
    WorldLayout,
    WorldSnapshot,
    WorldStop,
)

__all__ = [
    "ALL_PERMISSIONS",
    "FINGERS_CLOSED",
    "FINGERS_HOLDING",
    "FINGERS_OPEN",
    "MAC_ITEM_BYTES",
    "MAC_ITEM_COUNTERS",
    "MAC_ITEM_DTYPE",
    "MAC_ITEM_SPEEDS",
    "MAC_ITEM_STRUCT",
    "MAX_BUNDLED",
    "MAX_MESSAGE_BYTES",
    "AddItem",
    "AgentCommand",
    "AgentInfo",
    "AgentStates",
    "AuthEnvelope",
    "BundledCommand",
    "CommandBundle",
    "EditResult",
    "ErrorCode",
    "ErrorReply",
    "FloorLineInfo",
    "GripperReading",
    "Ident",
    "ItemInfo",
    "Lease",
    "LightInfo",
    "MacCommand",
    "MacCommandBundle",
    "MapRequest",
    "Message",
    "MessageError",
    "MoveItem",
    "OkReply",
    "PackedArray",
    "Permission",
    "RemoveItem",
    "ResetAgent",
    "RobotLook",
    "RobotTypeInfo",
    "RobotTypeReply",
    "RobotTypeRequest",
    "ResizeArena",
    "RotateItem",
    "SampleBundle",
    "SensorBatch",
    "SensorSample",
    "SessionToken",
    "ShapeInfo",
    "SignedToken",
    "WorldEdit",
    "WorldFrame",
    "WorldLayout",
    "WorldSnapshot",
    "WorldStop",
    "all_message_types",
    "decode",
    "encode",
    *_agent_all,
    *_audit_all,
    *_camera_all,
    *_chat_all,
    *_grading_all,
    *_host_all,
    *_lti_all,
    *_recording_all,
    *_registry_all,
    *_twin_all,
]
