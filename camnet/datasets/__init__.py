"""Readers for public multi-camera datasets with published calibrations."""
