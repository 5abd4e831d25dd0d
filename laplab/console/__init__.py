"""laplab console: DeepRacer console pages and JSON API over the job service (laplab serve)."""
