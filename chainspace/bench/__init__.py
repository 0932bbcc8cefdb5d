"""The benchmark suites behind ``chainspace bench``."""
