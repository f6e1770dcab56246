"""The ``bodyhealth`` command line: one module per command group under :mod:`cli.commands`.

It sits above every other package (it starts the service, runs the benchmarks and the sim-to-real
tooling), and nothing imports it.
"""

__all__: list[str] = []
