"""The ground floor: the error hierarchy, the artifact envelope, units. Imports nothing of ours."""
