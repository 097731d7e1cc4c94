"""Layer 9: the engines the commands run, each with its report and storage: ``paper``,
``fly``, ``margins``, ``compare``, ``tune/``, ``sweep/``, ``identify/`` and ``crosscheck/``.
A job takes a validated configuration and an output folder and returns its results;
``schema`` writes the JSON Schemas of the mission and job files.

May import every layer below (core … viz), not the commands (docs/architecture.md, "Layers")."""
