"""The platform's CCD camera of SPEC §3: it stores the train doors' shape and matches each frame.

A frame shows the doors as they were ``processing_delay_s`` before it is
delivered (grab and comparison with the stored shapes: the detection delay).
It is classified as one of three shapes ([interpretation], see ``platform.toml``):

* ``"closed"`` only with the leaves **fully shut** (the stored closed shape:
  no gap at all), so that the PSD never takes a door still closing for a
  closed one;
* ``"open"`` once the leaves are ``open_fraction`` of the way open or more;
* ``"moving"`` in between (a door opening or closing: neither shape).

A frame may be classified as one of the two other shapes
(``misread_probability``, each equally likely) or be unreadable
(``lost_frame_probability``). The camera cannot see the door locks: the PSD
control (``wayside.platform.PsdFollower``) counts the doors closed and locked
only after ``lock_confirm_s`` of "closed" frames. The randomness is passed in
(two uniforms per frame; DESIGN rule 7).
"""

from __future__ import annotations

from railstop.config.platform import DoorCamera

OPEN = "open"
MOVING = "moving"
CLOSED = "closed"
#: The shapes a frame may show, in a fixed order (the misread draw picks among the others by it).
SHAPES: tuple[str, str, str] = (OPEN, MOVING, CLOSED)


def true_shape(open_fraction: float, params: DoorCamera) -> str:
    """The shape of doors ``open_fraction`` open (0 shut, 1 fully open) as a correct frame shows it."""
    if open_fraction <= 0.0:
        return CLOSED  # SPEC §3 "closed": the leaves touch; any gap is not closed
    return OPEN if open_fraction >= params.open_fraction else MOVING


def classify(open_fraction: float, u_lost: float, u_misread: float, params: DoorCamera) -> str | None:
    """The frame of doors ``open_fraction`` open: "open", "moving", "closed", or None unreadable."""
    if u_lost < params.lost_frame_probability:
        return None
    truth = true_shape(open_fraction, params)
    p = params.misread_probability
    if u_misread >= p:
        return truth
    others = [s for s in SHAPES if s != truth]
    return others[0] if u_misread < 0.5 * p else others[1]
