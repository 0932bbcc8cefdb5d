"""Simulated filming: synthetic views of known motion, for tests, benchmarks and checking a set-up."""
