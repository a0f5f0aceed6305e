"""The live verbs' engines: run (daemon), demo, simulate."""
