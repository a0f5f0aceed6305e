"""`slipdaq report`: per log and maneuver, the slip study's plots and table, from slipdaq's own MCAP logs.

labels    -- `--label KEY=VALUE` on run/import/demo, stored as `label.KEY` in the log's metadata
summary   -- pure: estimate rows in, dataclasses out (maneuvers, linear region, Cx, Re, the table, the comparison)
fallback  -- stand-ins for fields newer logs carry (phase, online fitted Cx); to be removed later
plots     -- matplotlib Agg PNGs, fixed size, one colour per wheel
write     -- index.html, summary.json, summary.csv
build     -- make_report(): reads the logs and ties it together
"""
