// The source of the test suite's precompiled header (tests/CMakeLists.txt): the headers nearly
// every test includes, parsed once per build rather than once per test file.
