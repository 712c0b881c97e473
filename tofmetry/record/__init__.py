"""Guided recording with a device (``tofmetry record``): the warm-up, wall, board and object protocols.

* :mod:`~tofmetry.record.guidance` — the guidance as pure functions on arrays
* :mod:`~tofmetry.record.protocols` — one session class per protocol, writing the capture contract
  frame by frame
* :mod:`~tofmetry.record.runner` — the loop: device → session → status / operator prompts → preview
"""

from tofmetry.record.protocols import BoardSession, ObjectSession, WallSession, WarmupSession
from tofmetry.record.runner import RecordResult, answers_from, check_output, preview_image, run_recording
from tofmetry.record.session import Request, Session, Status

__all__ = ["BoardSession", "ObjectSession", "WallSession", "WarmupSession", "RecordResult", "Request", "Session",
           "Status", "answers_from", "check_output", "preview_image", "run_recording"]
