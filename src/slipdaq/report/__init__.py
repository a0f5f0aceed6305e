"""`slipdaq report`: per log and maneuver, the slip study's plots and tables, from slipdaq's own MCAP logs, as one
page an engineer explores in a browser (offline).

labels        -- `--label KEY=VALUE` on run/import/demo, stored as `label.KEY` in the log's metadata
summary       -- pure: estimate rows in, dataclasses out (maneuvers, linear region, Cx, Re, the table, the comparison)
style         -- names and colours shared by the page and the PNGs
traces        -- Plotly JSON: traces, layouts, the high-rate columns, min–max decimation (no drawing in Python)
page_maneuver -- a maneuver's plots: slip against time, speed, Fx, Re, Cx against slip
page_mu_brake -- μ against slip with its fit; speed against time with the brake test's and launch's marks
page_compare  -- a log's overview (decimated) and the comparison across logs by label
page_data     -- a log's figures by name as the script beside the page; plotly.js and the page's script (page.js)
page_tables   -- the page's tables: the maneuvers (sortable, linked), the logs, per maneuver, records, comparison
page          -- index.html
plots         -- `--png`: matplotlib Agg PNGs, fixed size (imported only then)
write         -- summary.json, summary.csv
build         -- make_report(), write_report(): reads the logs and ties it together
"""
