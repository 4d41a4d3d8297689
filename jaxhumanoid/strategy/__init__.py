"""Solution strategies: one stage (1S) and two stages (2S).

``settings`` (``SolveSettings``, the strategy's settings) -> ``runner`` (one NLP solve of a stage)
-> ``handover`` (from stage 1 to the dynamic stages) -> ``stage_one`` (stage 1 and its fallbacks)
-> ``solve`` (``solve``, ``make_solution``); ``problem``, ``posture``, ``solution`` and
``taskfile`` beside them.
"""
