"""What the camera sees: a tree's textured meshes, the background, and the renderer."""
