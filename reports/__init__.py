"""Figures and PDF reports (not implemented yet: see the open report issue)."""
