"""The browser UI's own code: the figures its pages draw (templates and static files beside it)."""
