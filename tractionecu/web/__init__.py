"""The read-only in-cab page served by the daemon (:mod:`.server`), every asset from this package."""
