"""Actions as a test author writes them, for the SDK's tests."""

from __future__ import annotations

from redline.testing import Action, Context, resolve


class Repeat(Action):
    """A custom action as a test author writes one: arguments in attributes, resolved in run."""

    def __init__(self, text: str | Action, times: int | Action) -> None:
        self.text = text
        self.times = times

    def run(self, ctx: Context) -> str:
        return str(resolve(self.text, ctx)) * int(resolve(self.times, ctx))
