"""I/O adapters: settings-independent readers and writers at the edge of the package."""
