"""Maneuvers: where each begins and ends (events), its figures (figures, linearity, mu_slip, brake_test), the live
`/maneuver` record and its validity (record), and the online detector that decides them as they end (detector).
Pure: rows and numbers in, dataclasses out; the pipeline (live, replay) and the report share it."""
