"""Measurement: the evaluation ladder, the system benchmarks, baselines, scoring of the
generator, stage 2 and posed sets, flicker and the stage-2 probes.
"""
