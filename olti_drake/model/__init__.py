"""model: joint spaces, error maps, position models of serial robots in 3D."""
