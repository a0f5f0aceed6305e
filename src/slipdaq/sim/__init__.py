"""Simulator: a vehicle + tire model (ground truth) and the raw WPT CAN frames and NMEA lines it would produce.

vehicle   -- kinematic model: speed profiles, Fx = M*a, tire slip from a simplified Pacejka curve, wheel angles.
dynamics  -- slip-driven model: commanded slips, load transfer, tire forces, a = sum(Fx_i)/M.
road_loads -- the car's road loads F0 + F1*v + F2*v_air^2 and rotating masses (truth; none unless given).
scenarios -- the slip commands of the dynamic scenarios (ABS, locked wheels, launch with spin) and the model per name.
sensors   -- the IMU, brake switch and reference speed as CAN frames, by the config's DBC names.
emit      -- the model turned into time-ordered raw records (CanFrame, NmeaLine) and truth samples.
realtime  -- plays the generated events on a python-can bus and a serial/pty writer in real time.
"""

from typing import Literal, get_args

ProfileScenario = Literal["accelerate", "brake", "cycle", "test-day", "highway"]
"""Scenarios of the kinematic model (a prescribed speed profile, slip from the inverse tire curve)."""
SlipScenario = Literal["brake-abs", "brake-abs-all", "brake-lock", "launch-spin", "coast-down"]
"""Scenarios of the slip-driven model (slip commanded per wheel, tire forces beyond the linear region)."""
Scenario = Literal[ProfileScenario, SlipScenario]

SCENARIOS: tuple[str, ...] = get_args(ProfileScenario) + get_args(SlipScenario)
"""Every scenario name, in the order the command line lists them."""
