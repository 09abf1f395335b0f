"""Scenes: the readers (NFF, OBJ, PLY, Open Inventor), the TOML sidecar, the builder
they share, polygon helpers and the reader's error; text in, `protocols.scene.SceneData` out."""
