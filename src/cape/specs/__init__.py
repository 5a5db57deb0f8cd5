"""Typed, frozen specifications of what a job reads, each built from a validated config in one
place (``from_config``); the code below the commands takes the spec, never the dict."""
