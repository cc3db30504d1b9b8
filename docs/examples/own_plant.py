import control
import numpy as np

from delaycomp import api
# the user's plant: 3 states, 2 inputs
A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.5, -1.0, 0.2]])
B = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
plant = control.ss(A, B, np.eye(3), np.zeros((3, 2)))
K_lqr, _, _ = control.lqr(plant, np.eye(3), np.eye(2))   # python-control: u = -K_lqr x
K = -K_lqr                                                # delaycomp: u = K x

timing = dict(T=0.2, r=0.36, tau=0.4, N=20, x0=[1.0, -0.5, 0.25])
comp = api.run(api.lti(plant, K=K, **timing), 12.0, engine="inprocess")
bare = api.run(api.lti(plant, K=K, mode="uncompensated", **timing), 12.0,
               engine="inprocess")
print(f"|x(12)|: compensated {np.linalg.norm(comp.data[-1, :3]):.2e}, "
      f"uncompensated {np.linalg.norm(bare.data[-1, :3]):.2e}")
print(f"critical delay of the uncompensated loop: "
      f"{api.critical_delay(api.lti(plant, K=K, **timing)):.4f} s")
fig = api.plot([comp, bare], title="3 states, 2 inputs, LQR gain: T = 0.2, r = 0.36, tau = 0.4",
               labels=["compensated", "uncompensated"])
fig.savefig("own_plant.png", dpi=90)
