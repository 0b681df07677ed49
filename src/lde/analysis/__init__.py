"""Identification, accuracy metrics, studies and plots."""
