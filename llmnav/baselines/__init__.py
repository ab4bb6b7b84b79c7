"""Non-LLM baselines every LLM run is compared against: the oracle and frontier exploration."""
