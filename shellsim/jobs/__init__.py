"""Whole jobs (simulate, wind, render, ...): typed settings, each run by one function."""
