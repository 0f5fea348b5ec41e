"""Mechanisms: parameters (validated frozen dataclasses) plus a topology built from engine groups."""
