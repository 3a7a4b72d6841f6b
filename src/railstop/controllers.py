"""The names of the stop controllers (a foundation module: no imports, so the CLI can list them
without loading the compiled model).

- SPEC §1 ground TASC, in its three onboard configurations: config 1 through
  the train's brake controller; config 2 through the switching unit, the
  step code (SW1-SW3) or, on a PWM train, the PWM signal (SW11/SW12, claim
  14); config 3 PWM superimposed at the zero crossing;
- the conventional onboard ATO the ground TASC replaces (SPEC §1 "Problem"),
  positioned at station transponders, and the same ATO positioned by SPEC §2
  track-circuit corrections;
- SPEC §3 manual driving: a human driver (onboard.driver) under ATS with the
  station's code points, under ATC with option 1 or option 2 of the home
  block, or with no station codes (unaided), stopping by the platform lamps.
"""

from __future__ import annotations

TASC_BRAKE_CONTROLLER = "tasc-brake-controller"
TASC_STEP = "tasc-step"
TASC_PWM = "tasc-pwm"
TASC_SWITCHED_PWM = "tasc-switched-pwm"
ATO = "ato"
ATO_CORRECTED = "ato-corrected"

DRIVER_ATS = "driver-ats"
DRIVER_ATC1 = "driver-atc1"
DRIVER_ATC2 = "driver-atc2"
DRIVER_UNAIDED = "driver-unaided"

TASC_CONTROLLERS: tuple[str, ...] = (TASC_BRAKE_CONTROLLER, TASC_STEP, TASC_SWITCHED_PWM, TASC_PWM)
ATO_CONTROLLERS: tuple[str, ...] = (ATO, ATO_CORRECTED)
DRIVER_CONTROLLERS: tuple[str, ...] = (DRIVER_ATS, DRIVER_ATC1, DRIVER_ATC2, DRIVER_UNAIDED)
#: Controllers without a wayside TASC unit and its radio link.
ONBOARD_CONTROLLERS: tuple[str, ...] = (*ATO_CONTROLLERS, *DRIVER_CONTROLLERS)
CONTROLLERS: tuple[str, ...] = (*TASC_CONTROLLERS, *ATO_CONTROLLERS, *DRIVER_CONTROLLERS)
# Stop-control laws loaded from users' files in this process (railstop.control.law): name ->
# positioning ("transponders": as ato, "corrected": as ato-corrected).
_LAWS: dict[str, str] = {}


def register_law(name: str, positioning: str) -> None:
    """Make a loaded law a controller of this process (``railstop.control.law.load_law_file``)."""
    _LAWS[name] = positioning


def known_controllers() -> tuple[str, ...]:
    """The built-in controllers, then the laws loaded in this process."""
    return (*CONTROLLERS, *_LAWS)


def is_ato_like(name: str) -> bool:
    """An onboard law positioned as the ATO (``ato``, ``ato-corrected`` or a loaded law)."""
    return name in ATO_CONTROLLERS or name in _LAWS


def is_corrected(name: str) -> bool:
    """Positioned by SPEC §2 track-circuit corrections (``ato-corrected`` or a law declaring so)."""
    return name == ATO_CORRECTED or _LAWS.get(name) == "corrected"


def is_onboard(name: str) -> bool:
    """No wayside TASC unit and radio link (an ATO, a loaded law or a driver)."""
    return name in ONBOARD_CONTROLLERS or name in _LAWS
