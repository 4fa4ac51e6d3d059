"""Speed benchmarks (``igdrivsim bench data|sim|train|pipeline``): the top layer beside the CLI,
so that nothing the library runs imports them. Results kept in the repository: docs/bench/."""
