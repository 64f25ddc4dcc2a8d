"""How much CPU work the objectbuilder spends per pair of legs (a revision changes this line),
and how it answers ``objectbuilder/locate`` queries."""

WORK_PER_PAIR = 1000
REPLY_DELAY_US = 0  # waited before each reply
DROP_EVERY = 0  # N: every Nth query is left unanswered (the caller times out); 0: none
