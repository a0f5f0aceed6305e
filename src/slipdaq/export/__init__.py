"""The export formats (CSV, MF4, Parquet: functions over rows) and the export verb's engine (run)."""
