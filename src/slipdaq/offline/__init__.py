"""The offline runs over recorded logs: import, replay, two-pass (run), recover."""
