"""Pictures: maps, overlays, flow."""
