def pytest_generate_tests(metafunc):
    if "fault_name" in metafunc.fixturenames:
        metafunc.parametrize("fault_name", getattr(metafunc.cls, "FAULTS", ()))
