"""Comparing search arms over repeated campaigns: statistics, inputs, report."""
