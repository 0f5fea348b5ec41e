"""Metrics: exact extremes of a path over an interval, deviation from a guide, minimum-zone fit."""
