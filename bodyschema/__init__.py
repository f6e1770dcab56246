"""The science of bodyhealth, pure: arrays and trees in, arrays and trees out.

Nothing in this package reads files, opens sockets, touches a database or looks at a clock; callers
hand it arrays (a :class:`~bodyschema.recording.Recording`) and get back trees, matrices and findings.
"""
