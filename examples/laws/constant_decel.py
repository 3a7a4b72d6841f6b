"""An example stop-control law for railstop (docs/control-law.md).

The simplest law there is: the constant deceleration that stops the train
exactly at its stopping point, read where the brakes will act (one brake
response ahead), less what the gradient and the running resistance give.
It has no memory, so it uses no state.
"""

from railstop.control.law import control_law


@control_law(name="constant-decel")
def constant_decel(meas, state, params):
    m = meas[0]  # what the train measures now
    p = params[0]  # the train's nominal brake data
    # Where the train will be when a demand made now acts.
    ahead = m.distance_m - m.speed_mps * p.response_s
    if ahead <= 0.5:
        return p.full_service_mps2  # too close to plan: brake fully
    # v^2 = 2 a s: the deceleration that stops the train in the distance left ...
    needed = m.speed_mps**2 / (2.0 * ahead)
    # ... of which the gradient and the resistance give this much (+: they help).
    return needed - m.external_mps2
