"""The tire as a model others use: the Magic Formula (MF-Tyre 6.1) pure longitudinal force, its fit to a log's
maneuvers and its property file (`.tir`)."""
