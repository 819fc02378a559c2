"""Interoperability: conversions from and to Open3D, and the HTML page of a registration."""
