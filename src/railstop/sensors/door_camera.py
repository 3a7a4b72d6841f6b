"""The platform's CCD camera of SPEC §3: it stores the train doors' shape (open / closed).

A frame shows the doors as they were ``processing_delay_s`` before it is
delivered (grab and comparison with the stored shapes: the detection delay).
The image matches "open" once the door leaves are ``open_fraction`` of the way
open ([interpretation], see ``platform.toml``). A frame may be classified as
the other shape (``misread_probability``) or be unreadable
(``lost_frame_probability``). The randomness is passed in (two uniforms per
frame; DESIGN rule 7).
"""

from __future__ import annotations

from railstop.config.platform import DoorCamera


def classify(open_fraction: float, u_lost: float, u_misread: float, params: DoorCamera) -> bool | None:
    """The frame of doors ``open_fraction`` open (0 closed, 1 fully open): True open, False
    closed, None unreadable."""
    if u_lost < params.lost_frame_probability:
        return None
    truth = open_fraction >= params.open_fraction
    return (not truth) if u_misread < params.misread_probability else truth
