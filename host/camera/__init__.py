"""The camera: lens files (tables and TOML), the render's camera set up from the options,
focusing through the lens and autofocus."""
