"""Online identification of a simulated MR damper in Python, without Zenoh (the README shows this file)."""

from streamid import OnlineIdentifier, StreamConfig
from streamid.sim import get_device

damper = get_device("mr_damper")                       # a simulated MR damper, 200 Hz
t_ns, u, y = damper.simulate_seconds(30.0, seed=1)     # integer-ns times, velocity in, force out
ident = OnlineIdentifier(StreamConfig(window_s=6.0, update_every_s=6.0))
for k in range(0, len(t_ns), 200):                     # samples arrive one second at a time
    ident.learn_many(t_ns[k:k + 200], u[k:k + 200], y[k:k + 200], inputs=["velocity"], outputs=["force"])
    for update in ident.update_all():                  # identify what is due, here and now
        print(update.version, update.kind, update.code, f"free-run R² {update.metrics['r2_fr_val']:.3f}")
print(ident.model.summary() if ident.model else "no model yet")  # the champion; predict_one() forecasts
