"""Seeds of the random operating-envelope benchmark, kept apart: tune on one set, report on another.

A module of its own so that the command line's help texts can name them without importing numpy.
"""

# Each report's seed is run once, reported, and is a tuning seed from then on (it has been looked at):
# 2026-2086 were the reports of issue 12's rounds (docs/ROUNDS.md; the latest in the README's "What the envelope
# shows today").
EVALUATION_SEED = 2087  # the next report's seed: never run, never tuned on
PAST_REPORT_SEEDS = (2026, 2027, 2028, 2029, 2030, 2031, 2032, 2033, 2034, 2035, 2036, 2037, 2038, 2039, 2040, 2041, 2042, 2043, 2044, 2045, 2046, 2047, 2048, 2049, 2050, 2051, 2052, 2053, 2054, 2055, 2056, 2057, 2058, 2059, 2060, 2061, 2062, 2063, 2064, 2065, 2066, 2067, 2068, 2069, 2070, 2071, 2072, 2073, 2074, 2075, 2076, 2077, 2078, 2079, 2080, 2081, 2082, 2083, 2084, 2085, 2086)
TUNING_SEEDS = tuple(range(0, 100)) + PAST_REPORT_SEEDS  # seeds for tuning and debugging
# The tuning seeds as the help texts write them.
TUNING_SEEDS_TEXT = f"0-99 and {PAST_REPORT_SEEDS[0]}-{PAST_REPORT_SEEDS[-1]}"
