"""tofmetry: turn a consumer time-of-flight RGB-D camera into a measuring instrument."""

__version__ = "0.1.0"
