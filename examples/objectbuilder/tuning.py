"""How much CPU work the objectbuilder spends per pair of legs (a revision changes this line)."""

WORK_PER_PAIR = 1000
