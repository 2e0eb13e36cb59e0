"""Scenes: the labelled-mesh Scene, Replica's on-disk format, procedural scenes."""
