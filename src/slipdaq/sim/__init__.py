"""Simulator: a vehicle + tire model (ground truth) and the raw WPT CAN frames and NMEA lines it would produce.

vehicle  -- pure model: speed profiles, Fx = M*a, tire slip from a simplified Pacejka curve, wheel angles.
emit     -- the model turned into time-ordered raw records (CanFrame, NmeaLine) and truth samples.
realtime -- plays the generated events on a python-can bus and a serial/pty writer in real time.
"""
