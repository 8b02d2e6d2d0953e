"""Reading and writing needlekit's inputs and outputs (poses, results, exports)."""
