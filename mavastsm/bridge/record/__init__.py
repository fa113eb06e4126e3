"""The record: what a flight leaves behind, written by the session, read by the tools.

``flight_log`` (one CSV row per sample, and reading it back) and ``tracking_metrics`` (per-axis settling,
overshoot, errors). Imports nothing else of the bridge.
"""
