"""Benchmarks of the whole system.

``prosplat bench points`` (speed against error) and ``prosplat bench hard`` (hard cases).
"""
