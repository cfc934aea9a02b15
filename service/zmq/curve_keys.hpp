#pragma once
// CURVE keys for a service listening beyond this machine: Z85 text files (40
// characters, '#' comments), as zmq_curve_keypair makes them. The server has a
// secret key and a list of client public keys it admits; a client has its own
// secret key and the server's public key.
#include <filesystem>
#include <set>
#include <string>

namespace pointillist::service {

struct CurveKeyPair {
  std::string publicKey;  // Z85
  std::string secretKey;  // Z85
};

// Throws UsageError when this libzmq was built without CURVE.
void requireCurve();
CurveKeyPair generateCurveKeyPair();
// The Z85 key of a file; InputError naming the file for anything else.
std::string readCurveKey(const std::filesystem::path& file);
std::string curvePublicKey(const std::string& secretZ85);
// One Z85 public key per line; returned as 32-byte binary keys, the form the
// ZAP handler is given.
std::set<std::string> readAuthorizedKeys(const std::filesystem::path& file);
// Writes PREFIX.secret (mode 0600) and PREFIX.public.
CurveKeyPair writeCurveKeyPair(const std::string& prefix);

}  // namespace pointillist::service
