"""Ball-screw preload design with CasADi (not implemented yet: see the open design issue)."""
